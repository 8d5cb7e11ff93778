"""What the odometry runner keeps as a run goes on (issue 22, item 9: memory of long runs): the
trajectory it writes, one compact row a camera frame, and nothing else that grows."""

from __future__ import annotations

import gc
import tracemalloc
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import quadnav.eval.metrics as eval_metrics
import quadnav.eval.vio_metrics as vio_metrics_module
import quadnav.geometry.trajectory as trajectory
from quadnav.eval import plots
from quadnav.eval.vio_metrics import RunCounts, pose_covariances, vio_metrics
from quadnav.experiments.odometry_run import (
    _STATE_BLOCK,
    OdometryRunOptions,
    _estimate,
    _score,
    _States,
)
from quadnav.geometry.rotations import Pose
from quadnav.geometry.trajectory import Trajectory
from quadnav.odometry import OdometryState

T0_NS = 1_700_000_000_000_000_000


def _state(k: int, rng: np.random.Generator) -> OdometryState:
    a = rng.normal(size=(6, 6))
    return OdometryState(
        t_ns=T0_NS + 50_000_000 * k,
        T_W_B=Pose(Rotation.from_rotvec(rng.normal(size=3)), rng.normal(size=3)),
        v_W_B=np.zeros(3), gyro_bias=np.zeros(3), accel_bias=np.zeros(3),
        cov_pose=a @ a.T, cov_v=np.eye(3),
    )  # fmt: skip


def test_a_camera_frame_costs_the_run_under_300_bytes() -> None:
    """36,000 frames (30 minutes at 20 Hz) of a row array each were 474 bytes a frame, 17 MB;
    blocks of rows hold stamp, pose and the covariance's triangle in 232."""
    rng = np.random.default_rng(0)
    states = [_state(k, rng) for k in range(3 * _STATE_BLOCK)]
    for st in states:
        st.T_W_B.R_A_B.as_quat()  # scipy caches on the Rotation: the state's, not the run's
    kept = _States()
    tracemalloc.start()
    try:
        for st in states:
            kept.append(st)
        per_frame = tracemalloc.get_traced_memory()[0] / len(states)
    finally:
        tracemalloc.stop()
    print(f"{per_frame:.0f} bytes a frame")
    assert per_frame < 300, f"{per_frame:.0f} bytes a frame"


def test_the_written_estimate_is_the_states_in_time_order_the_last_of_a_stamp() -> None:
    rng = np.random.default_rng(1)
    states = [_state(k, rng) for k in range(5000)]  # more than one block
    late = states[4100]
    again = _state(4100, rng)  # the same stamp again (a stereo pair completed late)
    kept = _States()
    for st in [*states, again]:
        kept.append(st)
    assert len(kept) == 5001 and kept.first_t_ns == states[0].t_ns
    est, triu = _estimate(kept)
    cov = pose_covariances(triu)
    assert len(est) == 5000 and np.all(np.diff(est.t_ns) > 0)
    for k, st in ((0, states[0]), (4099, states[4099]), (4100, again), (4999, states[4999])):
        assert est.t_ns[k] == st.t_ns
        np.testing.assert_allclose(est.p_W_B[k], st.T_W_B.p_A_B)
        R = Rotation.from_quat(est.q_W_B_xyzw[k])
        assert (R.inv() * st.T_W_B.R_A_B).magnitude() < 1e-12
        np.testing.assert_allclose(cov[k], st.cov_pose, rtol=1e-12)
    assert not np.allclose(cov[4100], late.cov_pose)
    empty_est, empty_cov = _estimate(_States())
    assert len(empty_est) == 0 and pose_covariances(empty_cov).shape == (0, 6, 6)


def _end_of_run_bytes(minutes: float) -> int:
    """What scoring and the metrics of a run of ``minutes`` (an estimate at 20 Hz with its
    covariances' triangles, a ground truth at 100 Hz, as a rendered dataset gives) hold at
    their peak above what the run hands them (traced bytes)."""
    rng = np.random.default_rng(2)

    def traj(n: int, period_ns: int, noise_m: float) -> Trajectory:
        t = T0_NS + period_ns * np.arange(n, dtype=np.int64)
        s = (t - T0_NS) * 1e-9
        p = np.column_stack([2 * np.cos(0.2 * s), 1.6 * np.sin(0.13 * s), 1.4 + 0 * s])
        R = Rotation.from_euler("zyx", np.column_stack([0.2 * s, 0.05 * np.sin(s), 0 * s]))
        return Trajectory(t_ns=t, p_W_B=p + noise_m * rng.normal(size=p.shape),
                          q_W_B_xyzw=R.as_quat(), name="vio")  # fmt: skip

    n = int(minutes * 60 * 20)
    truth, est = traj(5 * n, 10_000_000, 0.0), traj(n, 50_000_000, 0.01)
    cov = np.tile((1e-4 * np.eye(6))[np.triu_indices(6)], (n, 1))
    dataset = SimpleNamespace(groundtruth=SimpleNamespace(trajectory=truth))
    counts = RunCounts(frames=n, failures=0, reinitializations=0, rejected_images=0,
                       initialized_after_s=1.0)  # fmt: skip
    gc.collect()
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        opt = OdometryRunOptions(video=False)
        scored = _score(dataset, est, cov, int(est.t_ns[0]), int(est.t_ns[-1]), opt)  # type: ignore[arg-type]
        metrics = vio_metrics(
            scored.matched_truth, scored.matched_est, counts, cov_pose=scored.matched_cov
        )  # type: ignore[arg-type]
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    assert not isinstance(metrics.nees_pose, str) and not isinstance(metrics.rpe_10m, str)
    assert metrics.nees_pose.samples == n
    return peak


def test_scoring_a_run_costs_under_300_bytes_a_frame(monkeypatch: pytest.MonkeyPatch) -> None:
    """Between 2 and 8 minutes of camera frames (the slerp, RPE and NEES taking 1,024 rows at
    a time, as they take 8,192 of a 30-minute run's 36,000), scoring a run (the ground truth
    matched, APE, RPE, NEES) held ~1.8 kB a frame at its peak: the ground truth's span and the
    estimate copied, the (N, 6, 6) covariances twice, all RPE pairs' 4x4 error poses at once;
    with the plots, 65 MB more after 30 minutes than after 3."""
    monkeypatch.setattr(trajectory, "SLERP_CHUNK", 1024)
    monkeypatch.setattr(eval_metrics, "RPE_CHUNK", 1024)
    monkeypatch.setattr(vio_metrics_module, "NEES_CHUNK", 1024)
    short, long = _end_of_run_bytes(2.0), _end_of_run_bytes(8.0)
    per_frame = (long - short) / (6 * 60 * 20)
    print(f"{per_frame:.0f} bytes a frame")
    assert per_frame < 300, f"{per_frame:.0f} bytes a frame"


def test_the_runs_figures_draw_a_bounded_number_of_points(tmp_path: Path) -> None:
    """36,000 camera frames and 180,000 ground-truth poses (30 minutes) in the trajectory
    figure: each line at most :data:`~quadnav.eval.plots.MAX_PLOT_POINTS` points."""
    drawn: list[int] = []

    class Axes:
        def plot(self, x: np.ndarray, y: np.ndarray, *args: object, **kw: object) -> None:
            drawn.append(len(x))

        def __getattr__(self, name: str) -> object:
            return lambda *a, **k: None

    class Figure:
        def savefig(self, *a: object, **k: object) -> None:
            pass

    fake = SimpleNamespace(subplots=lambda *a, **k: (Figure(), (Axes(), Axes())),
                           close=lambda fig: None)  # fmt: skip

    def traj(n: int, period_ns: int) -> Trajectory:
        t = T0_NS + period_ns * np.arange(n, dtype=np.int64)
        return Trajectory(
            t_ns=t, p_W_B=np.zeros((n, 3)), q_W_B_xyzw=np.tile([0, 0, 0, 1.0], (n, 1))
        )

    import quadnav.experiments.odometry_report as report

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(report, "_pyplot", lambda: fake)
        report._plot_path(
            tmp_path / "t.png", traj(180_000, 10_000_000), traj(36_000, 50_000_000), T0_NS
        )
    assert len(drawn) == 4 and max(drawn) <= plots.MAX_PLOT_POINTS and min(drawn) > 1000
