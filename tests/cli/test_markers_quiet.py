"""`quadnav markers` on the README's own example (the thesis video) prints nothing from the
libraries: OpenCV warned `drawFrameAxes ... out of frame` on every frame with a pose."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from tests.shared_data import SHARED, needs

DATA = SHARED / "thesis_rig"


@needs(DATA)
def test_the_thesis_video_prints_nothing_from_the_libraries(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "quadnav", "markers", str(DATA / "board12_17.mp4"),
           "--params", str(DATA / "vision_params.yml"), "--camera", str(DATA / "cal.yml"),
           "--out", str(tmp_path), "--set", "max_frames=80"]  # fmt: skip
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    run = next(tmp_path.glob("*_markers"))
    assert (run / "overlay.mp4").stat().st_size > 10_000
    # piped, the progress is one plain line per tenth of the work (issue 12, item 26)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    progress = [ln for ln in lines if re.match(r"markers: \d+/80 \d+ poses \(\d+\.\d s\)$", ln)]
    assert 1 <= len(progress) <= 11
    # besides it, our own notes only (the thesis's parameters that mean nothing here)
    notes = [ln for ln in lines if ln not in progress]
    assert all(ln.startswith("note: ") for ln in notes), notes[:5]
    assert len(notes) <= 2
