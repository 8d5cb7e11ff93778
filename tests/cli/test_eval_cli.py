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
    table = runner.invoke(app, ["eval", "--table", str(run_dir), "--table-format", "csv"])
    assert table.exit_code == 0
    header, row = table.stdout.strip().splitlines()[:2]
    assert header.startswith("run,estimate") and ",est," in row


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
