"""Fixed-step integration: classic 4th-order Runge-Kutta (Simulink's ode4)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

__all__ = ["rk4_step"]

FloatArray = NDArray[np.float64]


def rk4_step(f: Callable[[FloatArray], FloatArray], x: FloatArray, dt_s: float) -> FloatArray:
    """One RK4 step of ``x' = f(x)`` (inputs held constant over the step, as a 1 kHz controller's are)."""
    k1 = f(x)
    k2 = f(x + 0.5 * dt_s * k1)
    k3 = f(x + 0.5 * dt_s * k2)
    k4 = f(x + dt_s * k3)
    return np.asarray(x + (dt_s / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4), dtype=np.float64)
