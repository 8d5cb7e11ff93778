"""Where a run's recording goes besides its folder: ``--rerun-connect ADDR`` streams it to a
rerun viewer or server listening there (loopback only), ``--rerun-spawn`` opens rerun's viewer
on it. Either implies ``--rerun``: the file is always written.

What was chosen: the child process that builds the recording (:mod:`quadnav.viz.background`)
writes the file and, with ``--rerun-connect``, sends the same stream to ADDR at once (two sinks
of one recording, the blueprint with it). Nothing listening at ADDR is one line said after the
run; the file is written all the same. ``--rerun-spawn`` starts the viewer on the finished file
(a display and the viewer binary needed; without them one line says so).
"""

from __future__ import annotations

import ipaddress
import socket
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

from quadnav.errors import IoError, VizError
from quadnav.io.run_folder import read_json
from quadnav.viz.recording import RECORDING_JSON, RecordingInfo, require_rerun

__all__ = ["RerunOptions", "listening_problem", "recording_info", "rerun_options", "rerun_url"]

#: The schemes of a rerun gRPC address.
SCHEMES = ("rerun+http", "rerun+https", "rerun")
#: How long the check that ADDR listens waits (s).
PROBE_TIMEOUT_S = 2.0


@dataclass(frozen=True, slots=True)
class RerunOptions:
    """A run's recording: written into its folder, and streamed to ``connect`` (a rerun gRPC
    URL) and/or opened in a viewer (``spawn``)."""

    connect: str | None = None
    spawn: bool = False


def rerun_url(addr: str, option: str = "--rerun-connect") -> str:
    """``addr`` (``HOST:PORT``, or a URL ``rerun+http://HOST:PORT/proxy``) as rerun's URL;
    a bad or non-loopback address is a one-line error naming ``option``."""
    text = addr.strip()
    url = text if "://" in text else f"rerun+http://{text}/proxy"
    why = ""
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as exc:
        parts, port, why = urlsplit(""), None, str(exc)
    host = parts.hostname or ""
    if not why and parts.scheme not in SCHEMES:
        why = f"the scheme is not one of {', '.join(SCHEMES)}"
    elif not why and (not host or port is None):
        why = "give HOST:PORT, e.g. 127.0.0.1:9876, or rerun+http://127.0.0.1:9876/proxy"
    elif not why and parts.path not in ("", "/proxy"):
        why = "the path of a rerun gRPC URL is /proxy"
    elif not why and not _loopback(host):
        why = f"{host} is not a loopback address (127.0.0.1, ::1, localhost); only loopback"
    if why:
        raise VizError(f"{option} {addr}: {why}")
    return f"{parts.scheme}://{parts.netloc}/proxy"


def _loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def rerun_options(rerun: bool, connect: str | None, spawn: bool) -> RerunOptions | None:
    """The options of ``--rerun``, ``--rerun-connect ADDR`` and ``--rerun-spawn`` (checked,
    rerun installed), None when none is given."""
    if not (rerun or connect is not None or spawn):
        return None
    require_rerun("--rerun")
    return RerunOptions(connect=None if connect is None else rerun_url(connect), spawn=spawn)


def listening_problem(url: str) -> str | None:
    """Why nothing can be streamed to ``url`` (None when something listens there)."""
    parts = urlsplit(url)
    try:
        with socket.create_connection((parts.hostname, parts.port), timeout=PROBE_TIMEOUT_S):
            return None
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        return f"--rerun-connect {parts.hostname}:{parts.port}: {reason.lower()}"


def recording_info(run_dir: Path) -> RecordingInfo | None:
    """The recording a run wrote into ``run_dir`` (None when it wrote none)."""
    path = Path(run_dir) / RECORDING_JSON
    if not path.is_file():
        return None
    try:
        data = read_json(path)
    except IoError:
        return None
    rows, every, url = data.get("rows"), data.get("every"), data.get("streamed_to")
    return RecordingInfo(
        path=Path(run_dir) / str(data.get("file", "recording.rrd")),
        size_bytes=int(data.get("size_bytes", 0)),  # type: ignore[call-overload]
        rows=dict(rows) if isinstance(rows, dict) else {},
        every=dict(every) if isinstance(every, dict) else {},
        streamed_to=str(url) if url else None, note=str(data.get("note") or ""),
    )  # fmt: skip
