from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.geometry import Trajectory
from quadnav.io import write_tum

runner = CliRunner()
EVO = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "evo"


def pair(tmp_path: Path, *, shift_s: float = 0.0) -> tuple[Path, Path]:
    rng = np.random.default_rng(0)
    n = 300
    t = 1_000_000_000_000 + np.arange(n) * 50_000_000
    p = np.cumsum(rng.normal(0, 0.1, (n, 3)), axis=0)
    q = Rotation.random(n, random_state=0).as_quat()
    ref = Trajectory(t_ns=t, p_W_B=p, q_W_B_xyzw=q)
    yaw = Rotation.from_euler("z", 0.4)
    est = Trajectory(
        t_ns=t + round(shift_s * 1e9),
        p_W_B=yaw.apply(p) + [1.0, 2.0, 0.0] + rng.normal(0, 0.01, (n, 3)),
        q_W_B_xyzw=(yaw * ref.R_W_B).as_quat(),
    )
    write_tum(tmp_path / "ref.tum", ref)
    write_tum(tmp_path / "est.tum", est)
    return tmp_path / "ref.tum", tmp_path / "est.tum"


def test_eval_writes_metrics_plots_and_report(tmp_path: Path) -> None:
    ref, est = pair(tmp_path)
    result = runner.invoke(
        app, ["eval", str(ref), str(est), "--align", "4dof", "--out", str(tmp_path / "runs")]
    )
    assert result.exit_code == 0, result.output
    run_dir = Path(result.stdout.strip().splitlines()[-1])
    metrics = json.loads((run_dir / "metrics.json").read_text())
    ape = metrics["estimates"]["est"]["ape_trans_m"]
    assert ape["rmse"] < 0.03  # 1 cm noise per axis after recovering yaw and offset
    assert metrics["estimates"]["est"]["alignment"]["method"] == "4dof"
    for name in ("xyz.png", "trajectories.png", "ape_est.png"):
        assert (run_dir / "plots" / name).stat().st_size > 10_000
    assert "data:image/png;base64" in (run_dir / "report.html").read_text()
    assert (run_dir / "aligned" / "est.tum").is_file()
    empty = tmp_path / "runs" / "not_a_run"
    empty.mkdir()
    replay = tmp_path / "runs" / "replay"
    replay.mkdir()
    (replay / "metrics.json").write_text('{"quadnav_vs_px4": {"horizontal_rms_m": 0.5}}')
    paths = [str(run_dir), str(replay), str(empty)]
    table = runner.invoke(app, ["eval", "--table", *paths, "--table-format", "csv"])
    assert table.exit_code == 0, table.output
    header, row, replay_row, none = table.stdout.strip().splitlines()
    assert header.startswith("run,kind,note,estimate") and ",eval,,est," in row
    assert replay_row.startswith("replay,replay,,") and ",quadnav vs px4,0.5" in replay_row
    assert none.startswith("not_a_run,,no metrics.json")


@pytest.mark.skipif(not (EVO / "KITTI_00_gt.txt").exists(), reason=f"shared data not at {EVO}")
def test_eval_on_kitti_prints_evos_numbers(tmp_path: Path) -> None:
    result = runner.invoke(
        app,
        ["eval", str(EVO / "KITTI_00_gt.txt"), str(EVO / "KITTI_00_ORB.txt"), "--align", "se3",
         "--rpe-delta", "10", "--rpe-unit", "metres", "--no-plots", "--out", str(tmp_path)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    metrics = json.loads(
        (Path(result.stdout.strip().splitlines()[-1]) / "metrics.json").read_text()
    )
    m = metrics["estimates"]["KITTI_00_ORB"]
    assert m["ape_trans_m"]["rmse"] == pytest.approx(1.3034497145650266, abs=1e-6)
    # evo 1.38.1: evo_rpe kitti KITTI_00_gt.txt KITTI_00_ORB.txt --delta 10 --delta_unit m -a
    assert m["rpe_trans_m"]["rmse"] == pytest.approx(0.23676346946465268, rel=1e-6)


@pytest.mark.parametrize(
    ("content", "fragment"),
    [
        ("1.0 0 0 0 0 0 0 1\n1.05 0 0 0 0", "est.tum:2: expected 8 values, got 5"),  # truncated
        ("1.0 0 0 0 0 0 0 1\n1.05 NaN 0 0 0 0 0 1\n", "est.tum:2: non-finite"),
        (
            "5000.0 0 0 0 0 0 0 1\n5000.05 0 0 0 0 0 0 1\n5000.1 0 0 1 0 0 0 1\n",
            "no overlapping time",
        ),
    ],
)
def test_bad_inputs_are_one_line_errors(tmp_path: Path, content: str, fragment: str) -> None:
    ref, est = pair(tmp_path)
    est.write_text(content)
    result = runner.invoke(app, ["eval", str(ref), str(est), "--out", str(tmp_path / "runs")])
    assert result.exit_code == 2
    assert fragment in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "runs").exists()


def test_time_offset_and_bad_options(tmp_path: Path) -> None:
    ref, est = pair(tmp_path, shift_s=3.0)
    base = [
        "eval",
        str(ref),
        str(est),
        "--no-plots",
        "--out",
        str(tmp_path / "runs"),
        "--align",
        "4dof",
    ]

    def ape_rmse(args: list[str]) -> float:
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
        metrics = json.loads(
            (Path(result.stdout.strip().splitlines()[-1]) / "metrics.json").read_text()
        )
        return float(metrics["estimates"]["est"]["ape_trans_m"]["rmse"])

    # A 3 s clock offset pairs the wrong poses; --t-offset puts them back.
    assert ape_rmse(base) > 0.1
    assert ape_rmse([*base, "--t-offset", "-3"]) < 0.03
    bad = runner.invoke(app, [*base, "--align", "7dof"])
    assert bad.exit_code == 2 and "--align" in bad.stderr
    one = runner.invoke(app, ["eval", str(ref)])
    assert one.exit_code == 2 and "at least one estimate" in one.stderr


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--t-offset", "inf"),
        ("--t-offset", "nan"),
        ("--t-offset", "1e300"),
        ("--t-max-diff", "inf"),
        ("--t-max-diff", "nan"),
        ("--t-max-diff", "-0.5"),
        ("--rpe-delta", "inf"),
        ("--rpe-delta", "nan"),
        ("--rpe-delta", "0"),
        ("--align-first", "0"),
        ("--gravity-axis", "w"),
        ("--rpe-unit", "km"),
        ("--format", "csv"),
    ],
)
def test_out_of_range_options_name_the_option(tmp_path: Path, option: str, value: str) -> None:
    ref, est = pair(tmp_path)
    args = ["eval", str(ref), str(est), "--no-plots", "--out", str(tmp_path / "runs")]
    result = runner.invoke(app, [*args, option, value])
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith(f"error: {option}: ")
    assert len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "runs").exists()


def test_an_offset_past_the_int64_range_is_refused(tmp_path: Path) -> None:
    ref, est = pair(tmp_path)
    # 3.9e9 s is within the bound of --t-offset, but added to stamps of 9e9 s it passes 2^63 ns.
    est.write_text("9000000000.0 0 0 0 0 0 0 1\n9000000000.05 1 0 0 0 0 0 1\n")
    result = runner.invoke(
        app,
        ["eval", str(ref), str(est), "--no-plots", "--t-offset", "3.9e9", "--out", str(tmp_path)],
    )
    assert result.exit_code == 2
    assert result.stderr.strip().startswith("error: --t-offset 3900000000.0 s moves the estimate")


def test_repeated_tum_timestamps_keep_the_first_and_say_so(tmp_path: Path) -> None:
    ref, est = pair(tmp_path)
    lines = est.read_text().splitlines()
    # Poses 10 and 20 appear twice (a logger that wrote the same stamp twice), once with junk.
    t10, t20 = lines[10].split()[0], lines[20].split()[0]
    lines.insert(11, f"{t10} 500 500 500 0 0 0 1")
    lines.insert(22, lines[21])
    est.write_text("\n".join(lines) + "\n")
    result = runner.invoke(
        app, ["eval", str(ref), str(est), "--align", "4dof", "--no-plots", "--out", str(tmp_path)]
    )
    assert result.exit_code == 0, result.output
    assert (
        "note: est.tum: 2 pose(s) repeat the timestamp of the line before (first at line 12)"
        in (result.stdout)
    )
    metrics = json.loads(
        (Path(result.stdout.strip().splitlines()[-1]) / "metrics.json").read_text()
    )
    m = metrics["estimates"]["est"]
    assert m["matched"] == 300  # the repeats are out, and the 500 m junk pose with them
    assert m["ape_trans_m"]["max"] < 0.1
    assert metrics["notes"][0].startswith("est.tum: 2 pose(s)")
    assert t20 in lines[21]


@pytest.mark.skipif(not (EVO / "KITTI_00_gt.txt").exists(), reason=f"shared data not at {EVO}")
def test_4dof_on_kitti_rotates_about_y_and_says_so(tmp_path: Path) -> None:
    def run(*extra: str) -> tuple[str, float]:
        result = runner.invoke(
            app,
            ["eval", str(EVO / "KITTI_00_gt.txt"), str(EVO / "KITTI_00_ORB.txt"), "--align",
             "4dof", "--no-plots", "--out", str(tmp_path), *extra],
        )  # fmt: skip
        assert result.exit_code == 0, result.output
        run_dir = Path(result.stdout.strip().splitlines()[-1])
        m = json.loads((run_dir / "metrics.json").read_text())["estimates"]["KITTI_00_ORB"]
        return result.stdout, float(m["ape_trans_m"]["rmse"])

    out, auto = run()
    assert "note: 4dof alignment rotates about y" in out
    out_y, about_y = run("--gravity-axis", "y")
    _, about_z = run("--gravity-axis", "z")
    assert "note:" not in out_y  # chosen by the user: nothing to say
    assert auto == about_y
    # KITTI's camera frame has y down: a yaw about z cannot turn the ground plane (x-z).
    assert about_z > 1.3 * about_y
