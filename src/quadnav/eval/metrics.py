"""Error statistics: RMSE and NEES over time-aligned arrays."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import EvalError

__all__ = ["nees", "position_rmse"]

FloatArray = NDArray[np.float64]


def position_rmse(p_est: FloatArray, p_ref: FloatArray) -> float:
    """Root mean square of the position error norm, ``sqrt(mean(|p_est - p_ref|^2))``."""
    a = np.asarray(p_est, dtype=np.float64)
    b = np.asarray(p_ref, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 2 or len(a) == 0:
        raise EvalError(
            f"position arrays must be (N, D) of equal shape, got {a.shape} and {b.shape}"
        )
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def nees(err: FloatArray, P: FloatArray) -> FloatArray:
    """Normalised estimation error squared ``e^T P^-1 e`` per row of ``err`` (N, n), ``P`` (N, n, n)."""
    e = np.asarray(err, dtype=np.float64)
    cov = np.asarray(P, dtype=np.float64)
    if e.ndim != 2 or cov.shape != (*e.shape, e.shape[1]):
        raise EvalError(f"NEES needs err (N, n) and P (N, n, n), got {e.shape} and {cov.shape}")
    sol = np.linalg.solve(cov, e[..., None])[..., 0]
    return np.asarray(np.sum(e * sol, axis=1), dtype=np.float64)
