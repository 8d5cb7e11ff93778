from __future__ import annotations

import datetime as dt
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from quadnav.errors import ConfigError, IoError
from quadnav.io import create_run_folder, write_csv, write_json
from quadnav.io.run_folder import (
    CsvAppender,
    finish_run_folder,
    read_run_status,
    require_complete,
    run_guard,
    write_text,
)


def test_run_folder_name_and_clash(tmp_path: Path) -> None:
    now = dt.datetime(2026, 1, 2, 3, 4, 5)
    a = create_run_folder(tmp_path, "planar test", now=now)
    b = create_run_folder(tmp_path, "planar test", now=now)
    assert a.name == "2026-01-02_03-04-05_planar-test"
    assert b.name == "2026-01-02_03-04-05_planar-test-2"
    assert (a / "plots").is_dir()


def test_csv_has_a_header_and_exact_integer_times(tmp_path: Path) -> None:
    t = np.array([1_700_000_000_123_456_789, 1_700_000_000_133_456_789], dtype=np.int64)
    write_csv(
        tmp_path / "a.csv", {"t_ns": t, "x_m": np.array([0.5, 1e-9]), "ok": np.array([True, False])}
    )
    lines = (tmp_path / "a.csv").read_text().splitlines()
    assert lines[0] == "t_ns,x_m,ok"
    assert lines[1] == "1700000000123456789,0.5,1"
    data = np.loadtxt(tmp_path / "a.csv", delimiter=",", skiprows=1, dtype=np.int64, usecols=0)
    np.testing.assert_array_equal(data, t)


def test_csv_refuses_bad_tables(tmp_path: Path) -> None:
    with pytest.raises(IoError, match="t_ns"):
        write_csv(tmp_path / "a.csv", {"x": np.zeros(2)})
    with pytest.raises(IoError, match="integer"):
        write_csv(tmp_path / "a.csv", {"t_ns": np.zeros(2)})
    with pytest.raises(IoError, match="equal length"):
        write_csv(tmp_path / "a.csv", {"t_ns": np.zeros(2, dtype=int), "x": np.zeros(3)})


def test_json_turns_nan_into_null(tmp_path: Path) -> None:
    write_json(tmp_path / "m.json", {"a": float("nan"), "b": np.float64(2.0), "c": np.arange(2)})
    assert json.loads((tmp_path / "m.json").read_text()) == {"a": None, "b": 2.0, "c": [0, 1]}


def test_unwritable_root_is_an_io_error(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(IoError):
        create_run_folder(blocker / "runs", "x")


# --- statuses, atomic files, no folder for nothing (issue 12, item 18) ---------------------


def _status(run_dir: Path) -> str:
    return str(json.loads((run_dir / "status.json").read_text())["status"])


def test_a_new_folder_says_running_until_finished(tmp_path: Path) -> None:
    d = create_run_folder(tmp_path, "x")
    assert _status(d) == "running"
    assert read_run_status(d) == "running"
    with pytest.raises(IoError, match="marked 'running'"):
        require_complete(d / "a.csv")
    finish_run_folder(d)
    assert read_run_status(d) == "complete"
    require_complete(d / "a.csv")  # no error once complete


def test_guard_marks_complete_interrupted_and_failed(tmp_path: Path) -> None:
    with run_guard():
        ok = create_run_folder(tmp_path, "ok")
        write_text(ok / "config.yaml", "a: 1\n")
        write_text(ok / "result.txt", "done\n")
    assert read_run_status(ok) == "complete"

    with pytest.raises(KeyboardInterrupt), run_guard() as kept:
        cut = create_run_folder(tmp_path, "cut")
        write_text(cut / "seed0.txt", "finished\n")
        raise KeyboardInterrupt
    assert kept == [cut] and read_run_status(cut) == "interrupted"
    assert (cut / "seed0.txt").read_text() == "finished\n"  # what finished is kept

    with pytest.raises(ValueError), run_guard():
        bad = create_run_folder(tmp_path, "bad")
        write_text(bad / "partial.txt", "x\n")
        raise ValueError("the solver diverged")
    assert read_run_status(bad) == "failed"
    assert "the solver diverged" in (bad / "status.json").read_text()


def test_a_folder_with_only_its_configuration_is_removed_on_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError), run_guard():
        d = create_run_folder(tmp_path, "early")
        write_text(d / "config.yaml", "a: 1\n")
        raise ConfigError("vision.delay_s: bad")
    assert not d.exists()
    assert list(tmp_path.iterdir()) == []


def test_an_interrupted_write_leaves_no_cut_file(tmp_path: Path, monkeypatch: Any) -> None:
    path = tmp_path / "delayed.csv"
    write_csv(path, {"t_ns": np.arange(3, dtype=np.int64), "x": np.zeros(3)})
    before = path.read_text()

    def cut_savetxt(fname: Any, *args: Any, **kwargs: Any) -> None:
        Path(fname).write_text("t_ns,x\n0,0.0\n1,")  # half a file, then Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savetxt", cut_savetxt)
    with pytest.raises(KeyboardInterrupt):
        write_csv(path, {"t_ns": np.arange(5, dtype=np.int64), "x": np.ones(5)})
    assert path.read_text() == before  # the old complete file, never the cut one
    assert [p.name for p in tmp_path.iterdir()] == ["delayed.csv"]  # no temporary left


def test_folders_from_before_statuses_read_as_unknown(tmp_path: Path) -> None:
    (tmp_path / "old").mkdir()
    assert read_run_status(tmp_path / "old") is None
    require_complete(tmp_path / "old" / "truth.csv")  # legacy folders are still readable


def test_csv_appender_writes_what_write_csv_writes_row_by_row(tmp_path: Path) -> None:
    cols = {"t_ns": np.array([5, 10], np.int64), "x_m": np.array([0.1, np.nan]), "ids": np.array(["1 2", "-"], dtype=object)}  # fmt: skip
    write_csv(tmp_path / "all.csv", cols)
    out = CsvAppender(tmp_path / "rows.csv", list(cols))
    out.append([5, 0.1, "1 2"])
    # flushed at once: a reader sees the row before the file is closed
    assert (tmp_path / "rows.csv").read_text().splitlines() == ["t_ns,x_m,ids", "5,0.1,1 2"]
    out.append([10, float("nan"), "-"])
    out.close()
    assert (tmp_path / "rows.csv").read_text() == (tmp_path / "all.csv").read_text()
    with pytest.raises(IoError, match="first CSV column must be t_ns"):
        CsvAppender(tmp_path / "bad.csv", ["x", "t_ns"])
    with CsvAppender(tmp_path / "short.csv", ["t_ns", "x"]) as short:
        with pytest.raises(IoError, match="a row of 1 values for 2 columns"):
            short.append([1])
        with pytest.raises(IoError, match="integer nanoseconds"):
            short.append([1.5, 2.0])
