"""Metrics that cannot be computed say why.

A metric of a run is a number, or a text ``"n/a: <why>"`` when the run gives it nothing to
measure (a 2 s flight has no hover, a dropout that covers the whole flight leaves no sample
with vision). Nothing here warns or returns NaN for an empty selection; tables print the
reason, ``metrics.json`` keeps it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "Metric",
    "fmt_metric",
    "is_na",
    "max_or_na",
    "mean_or_na",
    "median_or_na",
    "na",
    "rms_or_na",
]

#: A metric's value: a number, or ``"n/a: why"``.
Metric = float | str

_PREFIX = "n/a: "


def na(reason: str) -> str:
    """The value of a metric that cannot be computed, with the reason."""
    return _PREFIX + reason


def is_na(value: object) -> bool:
    return isinstance(value, str) and value.startswith(_PREFIX)


def _finite(values: ArrayLike) -> np.ndarray:
    a = np.asarray(values, dtype=np.float64).ravel()
    return a[np.isfinite(a)]


def rms_or_na(values: ArrayLike, reason: str) -> Metric:
    """Root mean square of the finite values (of norms, errors...), or ``n/a: reason``."""
    a = _finite(values)
    return float(np.sqrt(np.mean(a**2))) if len(a) else na(reason)


def mean_or_na(values: ArrayLike, reason: str) -> Metric:
    a = _finite(values)
    return float(np.mean(a)) if len(a) else na(reason)


def max_or_na(values: ArrayLike, reason: str) -> Metric:
    a = _finite(values)
    return float(np.max(a)) if len(a) else na(reason)


def median_or_na(values: Iterable[Metric], *, worst: bool = False) -> Metric:
    """Median (or with ``worst``, the maximum) over seeds of the numeric values; when no seed
    has a number, the first seed's reason."""
    vals = list(values)
    nums = [float(v) for v in vals if not isinstance(v, str) and math.isfinite(float(v))]
    if nums:
        return float(np.max(nums) if worst else np.median(nums))
    reasons = [v for v in vals if is_na(v)]
    return reasons[0] if reasons else na("no seed")


def fmt_metric(value: Any, spec: str = ".4g") -> str:
    """A table cell: the number formatted, or the reason as it is."""
    if isinstance(value, str):
        return value
    if isinstance(value, bool | int):
        return str(value)
    x = float(value)
    return format(x, spec) if math.isfinite(x) else "n/a"
