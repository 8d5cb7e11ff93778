"""The chi-square quantiles of quadnav.estimation.chi2 against scipy.stats' (the reference)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from quadnav.estimation.chi2 import chi2_isf, chi2_pdf, chi2_ppf, chi2_sf


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 6, 15, 600])
def test_the_quantiles_are_scipy_stats(dof: int) -> None:
    p = np.array([0.001, 0.025, 0.5, 0.95, 0.975, 0.9973, 0.999999])
    np.testing.assert_allclose(chi2_ppf(p, dof), chi2.ppf(p, dof), rtol=1e-10)
    np.testing.assert_allclose(chi2_isf(1 - p, dof), chi2.isf(1 - p, dof), rtol=1e-10)
    x = np.array([0.0, 0.1, 1.0, dof, 3.0 * dof + 10.0])
    np.testing.assert_allclose(chi2_sf(x, dof), chi2.sf(x, dof), rtol=1e-10, atol=1e-300)
    x_pdf = np.array([-1.0, 1e-3, 0.1, 1.0, dof, 3.0 * dof + 10.0])
    np.testing.assert_allclose(chi2_pdf(x_pdf, dof), chi2.pdf(x_pdf, dof), rtol=1e-10, atol=1e-300)
