"""The base of every YAML-validated configuration model.

Every configuration section inherits :class:`ConfigModel`: unknown keys are errors, models are
frozen, and every float must be finite (``inf`` and ``nan`` are refused with the key's name).
Numbers must also lie within a stated magnitude, :data:`MAX_ABS_VALUE`, unless a field states a
tighter bound itself; time spans that size arrays are bounded by :data:`MAX_DURATION_S`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Mapping
from typing import Any, Self

from pydantic import BaseModel, ConfigDict, model_validator

__all__ = [
    "MAX_ABS_VALUE",
    "MAX_DELAY_S",
    "MAX_DURATION_S",
    "MAX_RATE_HZ",
    "MAX_SIM_STEPS",
    "MIN_SIGMA",
    "ConfigModel",
    "check_finite_mapping",
]

#: The largest magnitude of any number in a configuration without a tighter bound of its own.
MAX_ABS_VALUE = 1e6
#: The longest simulated span (flight, experiment, hold): one hour.
MAX_DURATION_S = 3600.0
#: The largest sensor delay or arrival jitter.
MAX_DELAY_S = 10.0
#: The fastest sensor or log rate.
MAX_RATE_HZ = 100_000.0
#: The most simulation steps one run may take (its arrays are sized by them).
MAX_SIM_STEPS = 10_000_000
#: The smallest standard deviation a filter is told of: below it the covariances it inverts
#: underflow (a micrometre, a microradian).
MIN_SIGMA = 1e-6


def _numbers(value: Any, path: str) -> Iterator[tuple[str, float]]:
    """Every number inside ``value`` (tuples and lists too), with its key path."""
    if isinstance(value, bool):
        return
    if isinstance(value, int | float):
        yield path, float(value)
    elif isinstance(value, list | tuple):
        for i, v in enumerate(value):
            yield from _numbers(v, f"{path}[{i}]")


def check_finite_mapping(
    values: Mapping[str, Any], key: str, allowed: Iterable[str] | None = None
) -> None:
    """Refuse a free-form mapping (``--set key.name=value``) with a name not in ``allowed``
    or a value that is not a finite, bounded number (or list of them); errors name ``key``."""
    names = None if allowed is None else sorted(allowed)
    for name, v in values.items():
        if names is not None and name not in names:
            raise ValueError(f"{key}.{name}: unknown key (known: {', '.join(names)})")
        if isinstance(v, str):
            try:
                v = float(v)  # YAML reads inf and 1e9 as text
            except ValueError:
                raise ValueError(f"{key}.{name} must be a number, got {v!r}") from None
        for where, x in _numbers(v, f"{key}.{name}"):
            if not math.isfinite(x):
                raise ValueError(f"{where} must be a finite number, got {x}")
            if abs(x) > MAX_ABS_VALUE:
                raise ValueError(f"{where} must be within +-{MAX_ABS_VALUE:g}, got {x:g}")


class ConfigModel(BaseModel):
    """A configuration section: unknown keys refused, frozen, finite and bounded numbers."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @model_validator(mode="after")
    def _bounded_numbers(self) -> Self:
        for name in type(self).model_fields:
            for where, x in _numbers(getattr(self, name), name):
                if abs(x) > MAX_ABS_VALUE:
                    raise ValueError(f"{where} must be within +-{MAX_ABS_VALUE:g}, got {x:g}")
        return self
