"""VioEstimator on rendered sequences made in the test (the room, EuRoC's mono rig, a still
start then the built-in flight): the camera-rate trajectory against the ground truth after
posyaw alignment, over seeds. Slow (rendering and ~200 frames each)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from quadnav.eval.align import align
from quadnav.eval.associate import associate
from quadnav.eval.vio_metrics import NeesSummary, RunCounts, vio_metrics
from quadnav.experiments.datasets import make_dataset, sequence_spec
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.datasets import open_dataset
from quadnav.io.trajectory_io import read_tum
from quadnav.messages import ImuSample
from quadnav.odometry import TRACKING_EVENTS
from quadnav.vio import VioConfig, VioEstimator


def _run(
    root: Path, config: VioConfig | None = None
) -> tuple[Trajectory, VioEstimator, np.ndarray]:
    """The camera-rate estimate, the estimator and the estimate's pose covariances."""
    ds = open_dataset(root)
    vio = VioEstimator(ds.rig, config)
    t, p, q, cov = [], [], [], []
    for item in ds.stream():
        if isinstance(item, ImuSample):
            vio.push(item)
            continue
        s = vio.push(item)
        if s is not None:
            t.append(s.t_ns)
            p.append(s.T_W_B.p_A_B)
            q.append(s.T_W_B.R_A_B.as_quat())
            cov.append(s.cov_pose)
    est = Trajectory(t_ns=np.array(t, np.int64), p_W_B=np.array(p), q_W_B_xyzw=np.array(q))
    return est, vio, np.array(cov)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_room_flight_posyaw_ate(tmp_path: Path, seed: int) -> None:
    """10 s (1.5 s still, then ~3.5 m of flight at 0.45 m/s): ATE under 5 cm, no failure."""
    spec = sequence_spec(
        "room_easy",
        {"duration_s": 10.0, "still_s": 1.5, "rig": "euroc_mono", "seed": seed, "sensors": "ideal"},
    )
    made = make_dataset(spec, tmp_path / "seq", name="room_easy")
    est, vio, _ = _run(made.root)
    assert [e.kind for e in vio.events if e.kind in TRACKING_EVENTS] == ["initialized"], vio.events
    ref, e = associate(read_tum(made.root / "groundtruth.tum"), est, t_max_diff_s=0.006)
    aligned, _ = align(ref, e, "4dof")
    err = np.linalg.norm(aligned.p_W_B - ref.p_W_B, axis=1)
    assert made.distance_m > 2.5
    assert float(np.sqrt(np.mean(err**2))) < 0.05


@pytest.mark.slow
def test_pose_covariance_is_consistent_over_seeds(tmp_path: Path) -> None:
    """Monte Carlo over three seeds of 15 s of room_medium (a still start, then 0.9 m/s and
    fast turns), ideal sensors: the pose NEES / 6 the run reports, averaged over the seeds, in
    [0.5, 2]. The data's calibration is exact here, so the intrinsics are not refined, and the
    tracker detects corners on every frame (``detect_min_new=1``). With the defaults the NEES/6
    is 0.45-0.49, underconfident: with their 2 % prior the intrinsics allow for an error the data
    does not have, and detecting once 20 corners are missing (the faster front end) keeps tracks
    longer, which weighs vision, told a real camera's 1.5 px, more than ideal renders need (the
    results of 2026-12-02, part 3). On realistic sensors the results pages give the NEES over the
    shared motions.
    The features' noise is stated as ideal renders have it, 0.75 px (their KLT residuals after a
    solve are about 0.36 px): since the undistortion was made exact (643d032, found by bisection
    on 2026-12-04; this slow test was not run then), 1.5 px gives 0.28, 0.45, 0.65 (mean 0.46),
    1.0 px 0.35, 0.66, 0.85 (0.62), 0.75 px 0.43, 1.00, 1.01 (0.82).
    Before issue 22 it was several times over (the IMU integrated half a sample late, a
    track's old point as a prior, the NEES aligned over the whole run)."""
    means = []
    for seed in (0, 1, 2):
        spec = sequence_spec(
            "room_medium",
            {"duration_s": 15.0, "rig": "euroc_mono", "seed": seed, "sensors": "ideal"},
        )
        made = make_dataset(spec, tmp_path / f"seq{seed}", name="room_medium")
        tracker = VioConfig().tracker.model_copy(update={"detect_min_new": 1})
        config = VioConfig(estimate_intrinsics=None, tracker=tracker, pixel_sigma_px=0.75)
        est, vio, cov = _run(made.root, config)
        assert [e.kind for e in vio.events if e.kind in TRACKING_EVENTS] == ["initialized"], (
            vio.events
        )
        ref, e = associate(read_tum(made.root / "groundtruth.tum"), est, t_max_diff_s=0.006)
        counts = RunCounts(
            frames=len(est), failures=0, reinitializations=0, rejected_images=0,
            initialized_after_s=0.0,
        )  # fmt: skip
        m = vio_metrics(ref, e, counts, cov_pose=cov[np.searchsorted(est.t_ns, e.t_ns)])
        assert isinstance(m.nees_pose, NeesSummary)
        means.append(m.nees_pose.mean_over_dof)
    assert 0.5 < float(np.mean(means)) < 2.0, means
