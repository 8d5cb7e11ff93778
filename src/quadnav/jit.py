"""The one switch for compiled hot paths: numba's ``njit`` on the simulator's and the
controller's per-step kernels (the rigid body's RK4 step, the cascaded PID), cached on disk
next to the source so that only a fresh install compiles (a second or two, once).

``QUADNAV_JIT=0`` in the environment runs the same kernels as plain Python: the slow path,
which a test flies against the compiled one (same results within floating-point tolerance),
and a way round numba on a platform where it misbehaves. Kernels take and return numpy arrays
and floats only, and are written in scalars, so that both paths read the same.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any, TypeVar, cast

__all__ = ["JIT_ENABLED", "njit"]

F = TypeVar("F", bound=Callable[..., Any])

JIT_ENABLED = os.environ.get("QUADNAV_JIT", "1").strip() not in {"0", "false", "no", "off"}


def njit(func: F) -> F:
    """``func`` compiled by numba in nopython mode (no fast-math: IEEE results), or ``func``
    itself when ``QUADNAV_JIT=0``. Compiled lazily at the first call, then cached on disk."""
    if not JIT_ENABLED:
        return func
    import numba

    return cast(F, numba.njit(cache=True, fastmath=False, nogil=True)(func))
