"""``--loop-set KEY=VALUE``: loop closure's settings (:class:`~quadnav.loop.closer.LoopConfig`)
from the command line, a nested one by its dotted path (``graph.loop_sigma_m``,
``detector.temporal_consistency``, ``verification.min_inliers``). Each value is read as the
field's own type, and the dataclass checks it as it would in code; a bad key or value is a
one-line :class:`~quadnav.errors.LoopError` naming it."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

from quadnav.errors import LoopError, QuadnavError
from quadnav.loop.closer import LoopConfig

__all__ = ["loop_config_with", "loop_settings"]


def loop_settings(config: LoopConfig | None = None, prefix: str = "") -> dict[str, Any]:
    """Every setting by its dotted key, with its value."""
    config = config or LoopConfig()
    out: dict[str, Any] = {}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            out.update(loop_settings(value, f"{prefix}{f.name}."))  # type: ignore[arg-type]
        else:
            out[f"{prefix}{f.name}"] = value
    return out


def _parse(text: str, like: object, key: str) -> object:
    try:
        if isinstance(like, bool):
            if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError(text)
            return text.lower() in ("true", "1", "yes")
        if isinstance(like, int):
            return int(text)
        if isinstance(like, float):
            value = float(text)
            if not math.isfinite(value):
                raise ValueError(text)
            return value
    except ValueError:
        kind = type(like).__name__
        raise LoopError(f"--loop-set {key}={text}: not a finite {kind}") from None
    return text


def _replace(config: Any, path: list[str], value: str, key: str) -> Any:
    name, rest = path[0], path[1:]
    names = {f.name for f in dataclasses.fields(config)}
    if name not in names:
        raise LoopError(f"--loop-set {key}: unknown key (see docs/guide/loop.md)")
    current = getattr(config, name)
    nested = dataclasses.is_dataclass(current) and not isinstance(current, type)
    if nested != bool(rest):
        raise LoopError(
            f"--loop-set {key}: " + ("give one of its fields" if nested else "unknown key")
        )
    new = _replace(current, rest, value, key) if rest else _parse(value, current, key)
    try:
        return dataclasses.replace(config, **{name: new})
    except QuadnavError as exc:
        raise LoopError(f"--loop-set {key}: {exc}") from None


def loop_config_with(overrides: Sequence[str], base: LoopConfig | None = None) -> LoopConfig:
    """``base`` (the defaults) with each ``KEY=VALUE`` of ``overrides`` applied in order."""
    config = base or LoopConfig()
    for item in overrides:
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise LoopError(f"--loop-set {item!r}: give KEY=VALUE, e.g. max_drift_m=0.5")
        config = _replace(config, key.strip().split("."), value.strip(), key.strip())
    return config
