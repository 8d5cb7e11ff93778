"""YAML configuration files validated into typed models, with ``--set a.b=value`` overrides.

Every error is a :class:`~quadnav.errors.ConfigError` with one line naming the key.
"""

from __future__ import annotations

import copy
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from quadnav.errors import ConfigError

__all__ = ["RawConfig", "apply_override", "dump_config", "load_config", "yaml_problem"]

M = TypeVar("M", bound=BaseModel)

#: A configuration as read (a YAML file's top-level mapping, ``--set`` overrides applied to it),
#: before a model validates it. Input, not a result: it stays inside the loaders of ``io`` and
#: ``experiments``; what they return is the validated model.
RawConfig = dict[str, object]


def yaml_problem(path: Path, exc: yaml.YAMLError) -> str:
    """A YAML parse error in one line: ``<path>: <problem> at line L, column C``."""
    mark = getattr(exc, "problem_mark", None)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    problem = getattr(exc, "problem", None) or "invalid YAML"
    return f"{path}: {problem}{where}"


def _read_yaml(path: Path) -> RawConfig:
    if not path.exists():
        raise ConfigError(f"config file not found: {path}")
    if not path.is_file():
        raise ConfigError(f"config path is not a file: {path}")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read config file {path}: {exc}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(yaml_problem(path, exc)) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(
            f"{path}: the top level must be a mapping of keys, got {type(data).__name__}"
        )
    return data


def apply_override(data: RawConfig, override: str) -> None:
    """Apply one ``a.b.c=value`` override in place; the value is read as YAML (``1e-3``, ``true``)."""
    key, sep, raw = override.partition("=")
    key = key.strip()
    if not sep or not key or any(not part for part in key.split(".")):
        raise ConfigError(f"override {override!r} must look like key.subkey=value")
    try:
        value = yaml.safe_load(raw) if raw.strip() else None
    except yaml.YAMLError:
        value = raw
    parts = key.split(".")
    node = data
    for i, part in enumerate(parts[:-1]):
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ConfigError(f"override {key}: {'.'.join(parts[: i + 1])} is not a section")
        node = child
    node[parts[-1]] = value


_KEY_FIRST = re.compile(r"^[a-z][a-z0-9_]*(\[\d+\])*[ :]")


def _section_message(loc: str, msg: str) -> str:
    """A section's own message, keys named from the top: ``plan.hold_s must ...``."""
    if msg.startswith(f"{loc}."):
        return msg
    if _KEY_FIRST.match(msg):
        return f"{loc}.{msg}"
    return f"{loc}: {msg}"


def _format_validation_error(exc: ValidationError) -> str:
    parts = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"])
        msg = str(err["msg"]).removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            parts.append(f"{loc}: unknown key")
        elif loc and isinstance(err.get("input"), dict):
            parts.append(_section_message(loc, msg))  # a whole section's check
        elif loc:
            parts.append(f"{loc}: {msg} (got {err.get('input')!r})")
        else:
            parts.append(msg)
    return "; ".join(parts)


def load_config(
    model: type[M],
    path: Path | None = None,
    overrides: Iterable[str] = (),
    *,
    base: Mapping[str, object] | None = None,
) -> M:
    """Read ``path`` (or start from ``base``, else the defaults), apply overrides, validate
    into ``model``. ``base`` is copied, nested sections too: the overrides leave it as it was."""
    data = _read_yaml(Path(path)) if path is not None else copy.deepcopy(dict(base or {}))
    for override in overrides:
        apply_override(data, override)
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        where = f"{path}: " if path is not None else ""
        raise ConfigError(f"invalid config: {where}{_format_validation_error(exc)}") from None


def dump_config(config: BaseModel) -> str:
    """The resolved configuration as YAML (every field, defaults included)."""
    return yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False)
