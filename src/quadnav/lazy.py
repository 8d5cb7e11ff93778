"""Names a package loads on first use: its ``__getattr__`` imports each name from the module a
table gives, once, so that importing the package does not import what only some names need
(GTSAM, OpenCV, matplotlib)."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_getattr"]


def lazy_getattr(package: str, where: Mapping[str, str]) -> Callable[[str], Any]:
    """The module ``__getattr__`` of ``package``: ``where[name]`` is the module that holds
    ``name``; the value, once imported, is kept in the package so that the next use is plain."""

    def get(name: str) -> Any:
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(where[name]), name)
        setattr(sys.modules[package], name, value)
        return value

    return get
