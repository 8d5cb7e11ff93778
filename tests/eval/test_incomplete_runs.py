"""Readers check a run folder's status (issue 12, item 18): eval refuses a file of an
interrupted or failed run, and --table lists such a folder as incomplete."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from quadnav.errors import IoError
from quadnav.eval.runs import run_rows
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.run_folder import RunStatus, create_run_folder, finish_run_folder, write_json
from quadnav.io.trajectory_io import read_trajectory, write_tum


def _folder(root: Path, status: RunStatus) -> Path:
    d = create_run_folder(root, status)
    t = Trajectory(
        t_ns=np.arange(5, dtype=np.int64) * 10**8,
        p_W_B=np.zeros((5, 3)),
        q_W_B_xyzw=np.tile([0.0, 0.0, 0.0, 1.0], (5, 1)),
    )
    write_tum(d / "handled" / "output.tum", t)
    write_json(d / "metrics.json", {"kind": "planar", "table": [{"experiment": "x", "rmse": 1.0}]})
    finish_run_folder(d, status)
    return d


@pytest.mark.parametrize("status", ["interrupted", "failed", "running"])
def test_files_of_an_incomplete_run_are_refused(tmp_path: Path, status: RunStatus) -> None:
    d = _folder(tmp_path, status)
    with pytest.raises(IoError, match=f"marked '{status}'"):
        read_trajectory(d / "handled" / "output.tum")
    (row,) = run_rows(d)
    assert row.note == f"marked {status}: its results are incomplete" and not row.cells


def test_a_complete_run_reads(tmp_path: Path) -> None:
    d = _folder(tmp_path, "complete")
    assert len(read_trajectory(d / "handled" / "output.tum").t_ns) == 5
    (row,) = run_rows(d)
    assert row.note == "" and row.cells["rmse"] == 1.0


def test_a_table_shows_why_a_metric_is_missing(tmp_path: Path) -> None:
    d = create_run_folder(tmp_path, "short")
    why = "n/a: run not longer than the delay: the delayed horizon never moved (a long reason)"
    write_json(d / "metrics.json", {"kind": "planar", "table": [{"experiment": "x", "rmse": why}]})
    finish_run_folder(d)
    (row,) = run_rows(d)
    assert row.cells["rmse"] == why
