"""Files, folders and (later) links: configs, run folders, trajectory formats."""

from quadnav.errors import ConfigError, IoError
from quadnav.io.config import apply_override, dump_config, load_config
from quadnav.io.run_folder import create_run_folder, write_csv, write_json, write_text, write_tum

__all__ = [
    "ConfigError",
    "IoError",
    "apply_override",
    "create_run_folder",
    "dump_config",
    "load_config",
    "write_csv",
    "write_json",
    "write_text",
    "write_tum",
]
