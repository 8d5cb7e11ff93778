"""Files, folders and (later) links: configs, run folders, trajectory formats."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from quadnav.errors import ConfigError, IoError
from quadnav.io.run_folder import create_run_folder, write_csv, write_json, write_text
from quadnav.io.trajectory_io import (
    guess_format,
    read_trajectory,
    write_euroc,
    write_kitti,
    write_trajectory,
    write_tum,
)

if TYPE_CHECKING:  # configs (yaml, config models) load on first use: eval needs none of them
    from quadnav.io.config import apply_override, dump_config, load_config
    from quadnav.io.datasets import open_dataset

__all__ = [
    "ConfigError",
    "IoError",
    "apply_override",
    "create_run_folder",
    "dump_config",
    "guess_format",
    "load_config",
    "open_dataset",
    "read_trajectory",
    "write_csv",
    "write_euroc",
    "write_json",
    "write_kitti",
    "write_text",
    "write_trajectory",
    "write_tum",
]


def __getattr__(name: str) -> Any:
    if name in ("apply_override", "dump_config", "load_config"):
        value = getattr(importlib.import_module("quadnav.io.config"), name)
        globals()[name] = value
        return value
    if name == "open_dataset":  # datasets (cv2, rosbags) load on first use too
        value = importlib.import_module("quadnav.io.datasets").open_dataset
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
