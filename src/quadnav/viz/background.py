"""A run's recording built by a child process started when the run starts: it imports rerun
(most of a recording's cost on a short run) while the run goes on, on another core, then waits
for the finished folder and builds its recording from the files, as ``quadnav view`` would.

With :class:`~quadnav.viz.stream.RerunOptions`, the child streams the recording to a viewer
as it writes it (``connect``) and opens the viewer on the file (``spawn``); what could not be
done is the recording's note (in ``recording.json``), the file written all the same.

The parent sends one line, ``KIND<TAB>RUN_DIR<TAB>URL<TAB>SPAWN`` (a kind of
:mod:`quadnav.viz.folders`; the URL empty when not streaming; SPAWN 1 or 0), and reads back one line of JSON, the :class:`RecordingInfo`. A child that fails says
why on its last line of stderr, which becomes a one-line :class:`VizError` naming ``--rerun``.
If the run fails first, the child sees its input closed and exits without writing anything.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import weakref
from pathlib import Path

from quadnav.errors import VizError
from quadnav.viz.folders import KINDS
from quadnav.viz.recording import RecordingInfo
from quadnav.viz.stream import RerunOptions

__all__ = ["RecordingProcess"]
#: How long the parent waits for the child's recording (s).
TIMEOUT_S = 600.0


def _stop(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.wait()


class RecordingProcess:
    """The child process (see the module), started on construction."""

    def __init__(self, options: RerunOptions | None = None) -> None:
        import quadnav

        self._options = options or RerunOptions()
        # this quadnav, whatever the child's sys.path would find first
        root = str(Path(quadnav.__file__).resolve().parents[1])
        paths = [root, *[p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]]
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "quadnav.viz.background"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONPATH": os.pathsep.join(paths)},
        )
        self._finalizer = weakref.finalize(self, _stop, self._proc)
        self._line = ""  # the request sent (or to send)
        self._sent = False

    def start(self, run_dir: Path, kind: str) -> None:
        """Start the recording of ``run_dir`` (a ``kind`` folder) whose files the recording
        reads are written; the run may go on (its plots, its report) meanwhile."""
        if kind not in KINDS:
            raise VizError(f"--rerun: no recording of a {kind!r} folder")
        o = self._options
        self._line = f"{kind}\t{Path(run_dir)}\t{o.connect or ''}\t{int(o.spawn)}\n"
        try:
            assert self._proc.stdin is not None
            self._proc.stdin.write(self._line)
            self._proc.stdin.flush()
            self._sent = True
        except OSError:  # the child is gone: communicate() says why
            self._sent = False

    def record(self, run_dir: Path, kind: str) -> RecordingInfo:
        """The recording of the finished ``run_dir`` (a ``kind`` folder), written into it;
        after :meth:`start`, the one it started."""
        if not self._line:
            self.start(run_dir, kind)
        try:
            out, err = self._proc.communicate(None if self._sent else self._line, timeout=TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self._finalizer()
            raise VizError(f"--rerun: the recording took over {TIMEOUT_S:g} s; stopped") from None
        finally:
            self._finalizer()
        if self._proc.returncode != 0 or not out.strip():
            lines = [x for x in err.strip().splitlines() if x.strip()]
            raise VizError(f"--rerun: the recording failed: {lines[-1] if lines else 'no output'}")
        data = json.loads(out.strip().splitlines()[-1])
        return RecordingInfo(
            path=Path(data["path"]), size_bytes=int(data["size_bytes"]),
            rows=dict(data["rows"]), every=dict(data["every"]),
            streamed_to=data["streamed_to"], note=data["note"],
        )  # fmt: skip

    def close(self) -> None:
        """Stop the child (it has nothing to record)."""
        self._finalizer()


def _main() -> int:
    import numpy as np
    import rerun  # noqa: F401  (the point of the child: rerun imported while the run goes on)

    from quadnav.viz.folders import record_folder
    from quadnav.viz.nav_recording import nav_blueprint
    from quadnav.viz.odometry_recording import odometry_blueprint
    from quadnav.viz.recording import with_note
    from quadnav.viz.view import open_viewer

    # what rerun imports on first use (half a second for the first 3-D vector) while waiting
    nav_blueprint(np.zeros((2, 3)))
    odometry_blueprint("vio", np.zeros((2, 3)))

    line = sys.stdin.readline()
    if not line.strip():
        return 0  # the run ended without a folder to record
    kind, run_dir, url, spawn = (line.rstrip("\n").split("\t") + ["", "", "", "0"])[:4]
    try:
        info = record_folder(kind, Path(run_dir), complete=False, connect=url or None)
        problem = open_viewer(info.path) if spawn == "1" else None
        info = with_note(info, f"--rerun-spawn: {problem}" if problem else "")
    except Exception as exc:  # (reported to the parent as one line)
        print(f"{type(exc).__name__}: {exc}".replace("\n", " "), file=sys.stderr)
        return 1
    record = {"path": str(info.path), "size_bytes": info.size_bytes, "rows": info.rows,
              "every": info.every, "streamed_to": info.streamed_to, "note": info.note}  # fmt: skip
    print(json.dumps(record))
    return 0


if __name__ == "__main__":
    sys.exit(_main())
