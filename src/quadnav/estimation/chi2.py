"""The chi-square quantiles the gates and the consistency checks need, from ``scipy.special``
(``scipy.stats`` costs half a second of start-up for these three functions)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import chdtrc, chdtri

__all__ = ["chi2_isf", "chi2_ppf", "chi2_sf"]


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
