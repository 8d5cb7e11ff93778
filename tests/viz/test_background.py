"""Issue 27: the recording built by a child process started with the run (rerun imported while
the run goes on): the same recording as built in the process, and its failure in one line."""

from __future__ import annotations

from pathlib import Path

import pytest

from quadnav.errors import VizError
from quadnav.viz.background import RecordingProcess
from quadnav.viz.folders import record_folder

pytest.importorskip("rerun")

from tests.viz.rrd import rows_and_static
from tests.viz.test_nav_recording import run_dir  # noqa: F401  (the fixture: a short flight)


def test_the_child_writes_the_recording_the_process_would(run_dir: Path) -> None:  # noqa: F811
    (run_dir / "recording.rrd").unlink()
    info = RecordingProcess().record(run_dir, "nav")
    assert info.path == run_dir / "recording.rrd"
    assert info.size_bytes == info.path.stat().st_size > 0
    child_rows, _ = rows_and_static(info.path)
    assert child_rows == {k: v for k, v in info.rows.items() if v}
    here = record_folder("nav", run_dir)
    assert rows_and_static(here.path)[0] == child_rows and here.every == info.every


def test_a_failed_recording_is_one_line_naming_rerun(tmp_path: Path) -> None:
    with pytest.raises(VizError) as err:
        RecordingProcess().record(tmp_path, "nav")
    message = str(err.value)
    assert message.startswith("--rerun: the recording failed: IoError: ") and "\n" not in message
    assert str(tmp_path) in message
    with pytest.raises(VizError, match="no recording of a 'sweep' folder"):
        RecordingProcess().record(tmp_path, "sweep")
