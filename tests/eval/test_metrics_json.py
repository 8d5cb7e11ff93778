"""``quadnav eval``'s results are typed, and its ``metrics.json`` keeps the keys users' scripts read."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from quadnav.eval import ErrorStats, EstimateMetrics, EvalOptions, evaluate_pair, run_eval
from quadnav.geometry import Trajectory
from quadnav.io.trajectory_io import read_trajectory

STATS = ["rmse", "mean", "median", "std", "min", "max", "sse"]
METRICS = ["ape_trans_m", "ape_rot_deg", "ape_full", "rpe_trans_m", "rpe_rot_deg", "nees_pos"]
N = 200


def _csvs(tmp_path: Path, sigma_m: float = 0.05) -> tuple[Path, Path, np.ndarray]:
    """A reference and an estimate (quadnav CSVs, the estimate with variances), and the
    position error the estimate was given."""
    rng = np.random.default_rng(3)
    t = np.arange(N) * 100_000_000
    p = np.cumsum(rng.normal(0, 0.1, (N, 3)), axis=0)
    err = rng.normal(0, sigma_m, (N, 3))
    ref, est = tmp_path / "ref.csv", tmp_path / "est.csv"
    ref.write_text(
        "t_ns,x_m,y_m,z_m\n"
        + "".join(f"{t[k]},{p[k, 0]:.17g},{p[k, 1]:.17g},{p[k, 2]:.17g}\n" for k in range(N))
    )
    e = p + err
    var = sigma_m**2
    est.write_text(
        "t_ns,x_m,y_m,z_m,var_x,var_y,var_z\n"
        + "".join(f"{t[k]},{e[k, 0]:.17g},{e[k, 1]:.17g},{e[k, 2]:.17g},{var},{var},{var}\n" for k in range(N))
    )  # fmt: skip
    return ref, est, err


def test_an_estimate_s_metrics_are_typed_statistics(tmp_path: Path) -> None:
    ref_path, est_path, err = _csvs(tmp_path)
    ref = read_trajectory(ref_path)
    res = evaluate_pair(ref, read_trajectory(est_path), EvalOptions())
    assert isinstance(res.metrics, EstimateMetrics)
    norms = np.linalg.norm(err, axis=1)
    assert res.metrics.ape_trans_m.rmse == pytest.approx(np.sqrt(np.mean(norms**2)), rel=1e-9)
    assert res.metrics.ape_trans_m.max == pytest.approx(norms.max(), rel=1e-9)
    assert res.metrics.ape_rot_deg.max == 0.0  # both carry the identity attitude
    # NEES of 3 axes with the true variance: chi-square with 3 degrees of freedom, mean 3.
    assert res.metrics.nees_pos is not None and 2.5 < res.metrics.nees_pos.mean < 3.5
    names = [name for name, _ in res.metrics.named()]
    assert names == METRICS
    # Without covariances there is no NEES, and it is not listed.
    plain = Trajectory(t_ns=ref.t_ns, p_W_B=ref.p_W_B + err, q_W_B_xyzw=ref.q_W_B_xyzw)
    res = evaluate_pair(ref, plain, EvalOptions())
    assert res.metrics.nees_pos is None and "nees_pos" not in dict(res.metrics.named())
    assert "NEES mean" not in res.row()


def test_error_stats_by_evo_s_names() -> None:
    s = ErrorStats.of(np.array([3.0, 4.0]))
    assert s.rmse == pytest.approx(np.sqrt(12.5))
    assert (s.mean, s.median, s.min, s.max, s.sse) == (3.5, 3.5, 3.0, 4.0, 25.0)
    assert list(s.as_dict()) == STATS and s.as_dict()["std"] == pytest.approx(0.5)


def test_metrics_json_keeps_its_keys(tmp_path: Path) -> None:
    """The file's layout, key by key, as users' scripts read it."""
    ref, est, err = _csvs(tmp_path)
    run = run_eval(ref, [est], EvalOptions(plots=False), runs_root=tmp_path / "runs")
    data = json.loads((run.run_dir / "metrics.json").read_text())
    assert list(data) == ["kind", "reference", "estimates", "notes", "table"]
    assert data["kind"] == "eval" and data["reference"] == str(ref) and data["notes"] == []
    e = data["estimates"]["est"]
    assert list(e) == ["matched", "alignment", *METRICS]
    assert e["matched"] == N
    assert list(e["alignment"]) == ["method", "R", "t", "s", "n_used"]
    assert e["alignment"]["R"] == np.eye(3).tolist() and e["alignment"]["t"] == [0.0] * 3
    for name in METRICS:
        assert list(e[name]) == STATS, name
    norms = np.linalg.norm(err, axis=1)
    assert e["ape_trans_m"]["rmse"] == pytest.approx(np.sqrt(np.mean(norms**2)), rel=1e-9)
    assert e["ape_trans_m"]["sse"] == pytest.approx(np.sum(norms**2), rel=1e-9)
    (row,) = data["table"]
    assert list(row) == ["estimate", "matched", "align", "APE rmse (m)", "APE mean (m)", "APE max (m)",
                         "APE rot rmse (deg)", "RPE rmse (m)", "RPE rot rmse (deg)", "NEES mean"]  # fmt: skip
    assert (
        row["APE rmse (m)"] == e["ape_trans_m"]["rmse"]
        and row["NEES mean"] == e["nees_pos"]["mean"]
    )
