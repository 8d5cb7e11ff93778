"""Routh-Hurwitz stability of a characteristic polynomial, used to refuse unstable gains."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["routh_hurwitz_stable"]


def routh_hurwitz_stable(coeffs: Sequence[float]) -> bool:
    """True when every root of ``c0 s^n + c1 s^(n-1) + ... + cn`` has a negative real part.

    Builds the Routh array; the polynomial is Hurwitz when the first column has no sign
    change and no zero (a zero means a root on or symmetric about the imaginary axis).
    """
    c = np.asarray(coeffs, dtype=np.float64)
    if c.ndim != 1 or len(c) < 2 or c[0] == 0 or not np.isfinite(c).all():
        return False
    if c[0] < 0:
        c = -c
    n = len(c)
    cols = (n + 1) // 2
    rows = np.zeros((n, cols))
    rows[0, : len(c[0::2])] = c[0::2]
    rows[1, : len(c[1::2])] = c[1::2]
    tiny = 1e-12 * float(np.max(np.abs(c)))
    with np.errstate(all="ignore"):
        for i in range(2, n):
            a = rows[i - 1, 0]
            if abs(a) <= tiny:  # a zero in the first column: marginal at best
                return False
            for j in range(cols - 1):
                rows[i, j] = (a * rows[i - 2, j + 1] - rows[i - 2, 0] * rows[i - 1, j + 1]) / a
    first = rows[:, 0]
    return bool(np.isfinite(first).all() and np.all(first > tiny))
