"""Rerun recordings of run folders and ``quadnav view`` (the install extra ``quadnav[viz]``).

Importing this package imports no rerun: ``require_rerun`` checks the extra is installed, and the
builders import it when they run.
"""

from __future__ import annotations

from quadnav.viz.nav_recording import (
    MAX_ELLIPSOIDS,
    MAX_POINTS,
    MAX_SCALARS,
    write_nav_recording,
)
from quadnav.viz.recording import RECORDING_FILE, RECORDING_JSON, RecordingInfo, require_rerun
from quadnav.viz.view import ViewResult, view_run

__all__ = [
    "MAX_ELLIPSOIDS",
    "MAX_POINTS",
    "MAX_SCALARS",
    "RECORDING_FILE",
    "RECORDING_JSON",
    "RecordingInfo",
    "ViewResult",
    "require_rerun",
    "view_run",
    "write_nav_recording",
]
