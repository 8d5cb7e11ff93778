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
    itself when ``QUADNAV_JIT=0``. Compiled at the first call, then cached on disk; numba
    itself is imported only then, so a command that never runs a kernel does not pay for it
    (half a second of start-up)."""
    if not JIT_ENABLED:
        return func
    return cast(F, _LazyKernel(func))


class _LazyKernel:
    """A kernel until its first call: then numba compiles it (after every kernel its module
    refers to, which it puts in the module's names so that compiled code calls compiled code)
    and it calls the compiled function. ``py_func`` is the Python function, as numba's."""

    def __init__(self, func: Callable[..., Any]) -> None:
        self.py_func = func
        self.__name__ = func.__name__
        self.__qualname__ = func.__qualname__
        self.__doc__ = func.__doc__
        self._compiled: Callable[..., Any] | None = None

    def compiled(self) -> Callable[..., Any]:
        if self._compiled is None:
            import numba

            # (numba's dispatcher types and compiles at its first call, when the module's
            # kernels below are dispatchers too)
            self._compiled = numba.njit(cache=True, fastmath=False, nogil=True)(self.py_func)
            names = self.py_func.__globals__
            for key, value in list(names.items()):
                if isinstance(value, _LazyKernel):
                    names[key] = value.compiled()
        return self._compiled

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        fn = self._compiled if self._compiled is not None else self.compiled()
        return fn(*args, **kwargs)
