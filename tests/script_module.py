"""Load a script that is not part of the package (a benchmark, the docs' generator) as a module."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[1]


def load_script(path: Path, name: str | None = None) -> ModuleType:
    """Import the file at ``path`` (relative to the repository or absolute) under ``name``."""
    full = path if path.is_absolute() else ROOT / path
    module_name = name or full.stem
    spec = importlib.util.spec_from_file_location(module_name, full)
    assert spec is not None and spec.loader is not None, f"cannot load {full}"
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    spec.loader.exec_module(module)
    return module
