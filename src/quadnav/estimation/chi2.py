"""The chi-square quantiles the gates and the consistency checks need, from ``scipy.special``
(``scipy.stats`` costs half a second of start-up for these four functions)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import chdtrc, chdtri, gammaln, xlogy

__all__ = ["chi2_isf", "chi2_pdf", "chi2_ppf", "chi2_sf"]


def chi2_ppf(p: ArrayLike, dof: ArrayLike) -> NDArray[np.float64]:
    """The value a chi-square variable of ``dof`` degrees of freedom stays below with
    probability ``p`` (``scipy.stats.chi2.ppf``)."""
    return np.asarray(chdtri(dof, 1.0 - np.asarray(p, float)), float)


def chi2_sf(x: ArrayLike, dof: ArrayLike) -> NDArray[np.float64]:
    """The probability that a chi-square variable exceeds ``x`` (``scipy.stats.chi2.sf``)."""
    return np.asarray(chdtrc(dof, x), float)


def chi2_isf(q: ArrayLike, dof: ArrayLike) -> NDArray[np.float64]:
    """The value a chi-square variable exceeds with probability ``q`` (``chi2.isf``)."""
    return np.asarray(chdtri(dof, q), float)


def chi2_pdf(x: ArrayLike, dof: ArrayLike) -> NDArray[np.float64]:
    """The density of a chi-square variable of ``dof`` degrees of freedom at ``x``
    (``scipy.stats.chi2.pdf``): ``x^(k/2-1) e^(-x/2) / (2^(k/2) Gamma(k/2))``, 0 below 0."""
    x, k = np.asarray(x, float), np.asarray(dof, float)
    with np.errstate(divide="ignore"):
        log_pdf = xlogy(k / 2 - 1, x) - x / 2 - (k / 2) * np.log(2.0) - gammaln(k / 2)
    return np.asarray(np.where(x < 0, 0.0, np.exp(log_pdf)), float)
