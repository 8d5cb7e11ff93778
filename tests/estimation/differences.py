"""Central differences for checking analytic Jacobians."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def central_differences(
    fun: Callable[[np.ndarray], np.ndarray], n: int, eps: float = 1e-6
) -> np.ndarray:
    """``d fun / d x`` at ``x = 0`` (``fun`` takes an ``(n,)`` perturbation): column ``k`` is
    ``(fun(eps e_k) - fun(-eps e_k)) / (2 eps)``."""
    cols = []
    for k in range(n):
        d = np.zeros(n)
        d[k] = eps
        cols.append(
            (np.asarray(fun(d), dtype=float) - np.asarray(fun(-d), dtype=float)) / (2 * eps)
        )
    return np.stack(cols, axis=-1)
