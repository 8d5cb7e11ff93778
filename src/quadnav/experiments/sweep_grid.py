"""The grid of a parameter sweep: ``--grid KEY=SPEC`` parsed, bounded, and expanded into points.

A SPEC is ``start:stop:count`` (``count`` values from ``start`` to ``stop``, both included), a
list ``[a,b,c]`` (each read as YAML: numbers, words, lists) or one value. Sizes are checked
from the specs before any value is listed: a ``count`` above :data:`MAX_AXIS_COUNT`, more grid
points than :data:`MAX_GRID_POINTS` or more tasks (points x seeds) than :data:`MAX_TASKS` are
refused at once, naming the option.
"""

from __future__ import annotations

import itertools
import json
import math
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import yaml

from quadnav.errors import ConfigError
from quadnav.experiments.seeds import MAX_SEEDS, parse_seeds

__all__ = [
    "MAX_AXIS_COUNT",
    "MAX_GRID_POINTS",
    "MAX_TASKS",
    "GridAxis",
    "GridValue",
    "check_sweep_size",
    "grid_axis",
    "grid_points",
    "override",
    "parse_grid_option",
    "sweep_seeds",
]

#: The most values one ``start:stop:count`` may make.
MAX_AXIS_COUNT = 1_000
#: The most grid points (each is validated as a full configuration before anything runs).
MAX_GRID_POINTS = 10_000
#: The most tasks (grid points x seeds) one sweep may hold.
MAX_TASKS = 1_000_000
#: Keys a grid may not sweep: the seeds are ``--seeds``, the name is the scenario's.
RESERVED_KEYS = ("seed", "seeds", "name")

#: One value of a swept key, as YAML reads it (a number, a word, a list...).
GridValue = bool | int | float | str | list[object] | dict[str, object] | None

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_RANGE = re.compile(rf"\s*({_NUM})\s*:\s*({_NUM})\s*:\s*(\d+)\s*")
_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")


@dataclass(frozen=True, slots=True)
class GridAxis:
    """One swept key and its values, in the order given."""

    key: str
    values: tuple[GridValue, ...]


def _shown(key: str, spec: object) -> str:
    text = f"{key}={spec}"
    return f"--grid {text if len(text) <= 60 else text[:57] + '...'}"


def _linspace(key: str, spec: str, m: re.Match[str]) -> tuple[GridValue, ...]:
    """``start:stop:count`` as ``count`` values, both ends included; integers stay integers
    when both ends are written as integers and every value is whole."""
    a_text, b_text, n_text = m.groups()
    if len(n_text) > 7 or not 1 <= int(n_text) <= MAX_AXIS_COUNT:
        raise ConfigError(f"{_shown(key, spec)}: count must be 1 to {MAX_AXIS_COUNT:,}")
    a, b, n = float(a_text), float(b_text), int(n_text)
    if not (math.isfinite(a) and math.isfinite(b)):
        raise ConfigError(f"{_shown(key, spec)}: start and stop must be finite numbers")
    if n == 1 and a != b:
        raise ConfigError(f"{_shown(key, spec)}: one value from {a:g} to {b:g}? give count >= 2")
    values = [a + (b - a) * k / (n - 1) if n > 1 else a for k in range(n)]
    ints = all(re.fullmatch(r"[-+]?\d+", t) for t in (a_text, b_text))
    if ints and all(float(v).is_integer() for v in values):
        return tuple(int(v) for v in values)
    return tuple(float(f"{v:.12g}") for v in values)


def grid_axis(key: str, spec: object, *, from_text: bool = True) -> GridAxis:
    """One axis from its SPEC: text from the command line (read as YAML unless it is a range),
    or a value of a sweep file (a list, a number, or text that may be a range)."""
    if not _KEY.fullmatch(key):
        raise ConfigError(
            f"{_shown(key, spec)}: give the grid as KEY=SPEC, e.g. vision.delay_s=0:1:5"
        )
    if key in RESERVED_KEYS:
        raise ConfigError(f"--grid {key}: not a key to sweep (the seeds are --seeds)")
    value: object = spec
    if isinstance(spec, str):
        m = _RANGE.fullmatch(spec)
        if m is not None:
            return GridAxis(key, _linspace(key, spec, m))
        if ":" in spec and re.fullmatch(r"[-+.\deE:\s]+", spec):
            raise ConfigError(f"{_shown(key, spec)}: a range is start:stop:count, e.g. 0.05:0.5:10")
        if from_text:
            try:
                value = yaml.safe_load(spec) if spec.strip() else None
            except yaml.YAMLError:
                raise ConfigError(
                    f"{_shown(key, spec)}: not a value, a list or start:stop:count"
                ) from None
    values = tuple(value) if isinstance(value, list) else (value,)
    if not values:
        raise ConfigError(f"{_shown(key, spec)}: an empty list")
    if len(values) > MAX_AXIS_COUNT:
        raise ConfigError(f"{_shown(key, spec)}: at most {MAX_AXIS_COUNT:,} values")
    keys = [json.dumps(v, sort_keys=True, default=str) for v in values]
    if len(set(keys)) != len(keys):
        raise ConfigError(f"{_shown(key, spec)}: a value is given twice")
    return GridAxis(key, values)


def parse_grid_option(text: str) -> GridAxis:
    """``--grid KEY=SPEC``."""
    key, sep, spec = text.partition("=")
    if not sep:
        raise ConfigError(f"--grid {text}: give KEY=SPEC, e.g. vision.delay_s=0.05:0.5:10")
    return grid_axis(key.strip(), spec)


def check_sweep_size(axes: Sequence[GridAxis], n_seeds: int) -> int:
    """The number of tasks; a sweep too large to run from one command is refused."""
    keys = [a.key for a in axes]
    if len(set(keys)) != len(keys):
        twice = sorted({k for k in keys if keys.count(k) > 1})
        raise ConfigError(f"--grid {twice[0]}: given twice")
    points = math.prod(len(a.values) for a in axes)
    if points > MAX_GRID_POINTS:
        raise ConfigError(
            f"--grid: {points:,} grid points ({' x '.join(str(len(a.values)) for a in axes)}); "
            f"at most {MAX_GRID_POINTS:,} in one sweep"
        )
    if points * n_seeds > MAX_TASKS:
        raise ConfigError(
            f"--seeds: {points:,} grid points x {n_seeds:,} seeds = {points * n_seeds:,} tasks; "
            f"at most {MAX_TASKS:,} in one sweep"
        )
    return points * n_seeds


def grid_points(axes: Sequence[GridAxis]) -> Iterator[tuple[tuple[str, GridValue], ...]]:
    """Every combination of the axes' values, the last axis varying fastest."""
    for combo in itertools.product(*(a.values for a in axes)):
        yield tuple((a.key, v) for a, v in zip(axes, combo, strict=True))


def override(key: str, value: GridValue) -> str:
    """The ``--set`` override that gives ``key`` the grid value (JSON is YAML)."""
    return f"{key}={json.dumps(value)}"


def sweep_seeds(text: str, first: int) -> tuple[int, ...]:
    """``--seeds``: a count N (seeds ``first`` .. ``first + N - 1``, as ``quadnav run --seeds``)
    or seeds as ``quadnav vio --seeds`` names them (``0-4``, ``0,2,7``; one seed ``3-3``)."""
    text = text.strip()
    if text.isdigit():
        if len(text) > 6 or not 1 <= int(text) <= MAX_SEEDS:
            raise ConfigError(f"--seeds {text}: a count of 1 to {MAX_SEEDS:,} seeds")
        return tuple(range(first, first + int(text)))
    return parse_seeds(text, "--seeds")
