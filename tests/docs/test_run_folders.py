"""Every kind of run folder holds exactly the files ``quadnav.experiments.run_kinds`` declares
(the documentation's run-folder page is generated from it): a small instance of each kind is
made and its files compared with the declaration, both ways."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.experiments.run_kinds import RUN_FOLDER_KINDS, RunFile, RunFolderKind, check_run_files
from tests.shared_data import PX4_SITL, needs

runner = CliRunner()


def _files(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())


def _made(out: Path, args: list[str]) -> Path:
    """Run ``quadnav ARGS --out OUT`` and return the one folder it made in OUT."""
    result = runner.invoke(app, [*args, "--out", str(out)])
    assert result.exit_code == 0, result.output
    folders = [p for p in out.iterdir() if p.is_dir() and p.name != "datasets"]
    assert len(folders) == 1, folders
    return folders[0]


def _check(kind: str, folder: Path) -> None:
    problems = check_run_files(RUN_FOLDER_KINDS[kind], _files(folder))
    assert not problems, "\n".join(problems)
    if any(f.pattern == "status.json" for f in RUN_FOLDER_KINDS[kind].files):
        assert json.loads((folder / "status.json").read_text())["status"] == "complete"


def test_the_checker_finds_undeclared_and_missing_files() -> None:
    kind = RunFolderKind(
        title="k",
        command="c",
        folder="f",
        description="d",
        files=(RunFile("a.csv", "a"), RunFile("plots/*.png", "p"), RunFile("o.mp4", "o", False)),
    )
    assert check_run_files(kind, ["a.csv", "plots/x.png"]) == []
    assert check_run_files(kind, ["plots/x.png", "b.json"]) == [
        "b.json: not declared in 'k'",
        "a.csv: declared as required in 'k' but not written",
    ]


def test_every_command_that_writes_a_run_folder_is_declared() -> None:
    """Each create_run_folder call of the package belongs to a declared kind."""
    import quadnav

    root = Path(quadnav.__file__).parent
    writers = sorted(
        p.relative_to(root).as_posix()
        for p in root.rglob("*.py")
        if any(
            f in p.read_text(encoding="utf-8") for f in ("create_run_folder(", "open_run_folder(")
        )
        and p.name != "run_folder.py"
    )
    assert writers == [
        "eval/evaluate.py",  # eval
        "experiments/flight_study.py",  # sim
        "experiments/markers_run.py",  # markers
        "experiments/nav_study.py",  # run
        "experiments/odometry_run.py",  # vio (and any odometry)
        "experiments/odometry_study.py",  # vio_study
        "experiments/planar_study.py",  # planar
        "experiments/replay_run.py",  # replay
        "experiments/sweep.py",  # sweep
    ], "a new kind of run folder: declare its files in quadnav/experiments/run_kinds.py"


def test_run(tmp_path: Path) -> None:
    short = ["vision.source=pose", "plan.kind=takeoff_forward", "plan.takeoff_s=0.5",
             "plan.duration_s=1", "plan.height_m=0.5", "plan.forward_m=0.5"]  # fmt: skip
    args = ["run", "--jobs", "1", "--rerun", *[x for s in short for x in ("--set", s)]]
    folder = _made(tmp_path, args)
    _check("run", folder)
    assert (folder / "recording.rrd").is_file()  # the optional file --rerun adds


def test_planar(tmp_path: Path) -> None:
    args = ["planar", "--set", "duration_s=2", "--seeds", "2", "--jobs", "1"]
    _check("planar", _made(tmp_path, args))


def test_sim(tmp_path: Path) -> None:
    _check("sim", _made(tmp_path, ["sim", "thesis002_pd_stabilization", "--set", "duration_s=2"]))


def test_markers(tmp_path: Path) -> None:
    import cv2

    from quadnav.geometry.camera import thesis_camera
    from quadnav.io.opencv_yaml import write_camera_yaml
    from tests.cli.conftest import marker_views

    cam = thesis_camera()
    frames = tmp_path / "frames"
    frames.mkdir()
    for k, img in enumerate(marker_views(cam, 3)[0]):
        cv2.imwrite(str(frames / f"f{k:03d}.png"), img)
    write_camera_yaml(tmp_path / "cal.yml", cam)
    args = ["markers", str(frames), "--camera", str(tmp_path / "cal.yml"), "--set", "fps=10",
            "--set", "write_images=true"]  # fmt: skip
    _check("markers", _made(tmp_path / "out", args))


@needs(PX4_SITL)
def test_replay(tmp_path: Path) -> None:
    _check("replay", _made(tmp_path, ["replay", str(PX4_SITL)]))


def test_eval(tmp_path: Path) -> None:
    t = np.arange(50) * 0.1
    rows = [f"{s:.1f} {np.cos(s):.4f} {np.sin(s):.4f} 1 0 0 0 1" for s in t]
    (tmp_path / "ref.tum").write_text("\n".join(rows) + "\n")
    noisy = [f"{s:.1f} {np.cos(s) + 0.01:.4f} {np.sin(s):.4f} 1 0 0 0 1" for s in t]
    (tmp_path / "est.tum").write_text("\n".join(noisy) + "\n")
    args = ["eval", str(tmp_path / "ref.tum"), str(tmp_path / "est.tum")]
    _check("eval", _made(tmp_path / "out", args))


def test_sweep(tmp_path: Path) -> None:
    short = ["vision.source=pose", "plan.kind=takeoff_forward", "plan.takeoff_s=0.5",
             "plan.duration_s=1", "plan.height_m=0.5", "plan.forward_m=0.5"]  # fmt: skip
    args = ["sweep", "--grid", "vision.delay_s=[0.1,0.2]", "--jobs", "1",
            *[x for s in short for x in ("--set", s)], "--out", str(tmp_path / "s")]  # fmt: skip
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    _check("sweep", tmp_path / "s")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One second of the room through the one-camera EuRoC rig."""
    out = tmp_path_factory.mktemp("dataset") / "room"
    args = ["dataset", "make", "room_easy", "--rig", "euroc_mono", "--duration", "3"]
    result = runner.invoke(app, [*args, "--out", str(out)])
    assert result.exit_code == 0, result.output
    return out


def test_dataset_make(dataset: Path) -> None:
    _check("dataset_make", dataset)


def test_vio(dataset: Path, tmp_path: Path) -> None:
    _check("vio", _made(tmp_path, ["vio", str(dataset)]))


def test_vio_study(dataset: Path, tmp_path: Path) -> None:
    shutil.copytree(dataset, tmp_path / "again")
    args = ["vio", str(dataset), str(tmp_path / "again"), "--no-video"]
    _check("vio_study", _made(tmp_path / "out", args))
