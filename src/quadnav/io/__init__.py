"""Files, folders and (later) links: configs, run folders, trajectory formats."""

from quadnav.errors import ConfigError, IoError
from quadnav.io.config import apply_override, dump_config, load_config
from quadnav.io.run_folder import create_run_folder, write_csv, write_json, write_text
from quadnav.io.trajectory_io import (
    guess_format,
    read_trajectory,
    write_euroc,
    write_kitti,
    write_trajectory,
    write_tum,
)

__all__ = [
    "ConfigError",
    "IoError",
    "apply_override",
    "create_run_folder",
    "dump_config",
    "guess_format",
    "load_config",
    "read_trajectory",
    "write_csv",
    "write_euroc",
    "write_json",
    "write_kitti",
    "write_text",
    "write_trajectory",
    "write_tum",
]
