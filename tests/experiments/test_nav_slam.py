"""Issue 24, item 7: ``quadnav run indoor_slam``, the navigation EKF fed by the stereo SLAM's
pose (EuRoC's stereo rig rendered in the hall, synthetic images). A short flight (take off to
1.5 m, 1.5 m forward) flown on the truth, so that both filters see the same flight and the same
IMU: fed by the SLAM, the EKF holds the position; given the heading but no position (the IMU
alone for the position), the same EKF drifts past the bound."""

from __future__ import annotations

import pytest

from quadnav.experiments.nav import run_nav
from quadnav.experiments.nav_study import NavMetrics, nav_metrics
from quadnav.experiments.scenarios import nav_builtin

SEEDS = (0, 1, 2)
#: 7.5 s: 0.5 s levelling, 1 s on the ground, 6 s of take-off, forward and hover
SHORT = (
    "closed_loop=false",
    "plan.height_m=1.5",
    "plan.forward_m=1.5",
    "plan.takeoff_s=1",
    "plan.duration_s=6",
)
BOUND_M = 0.1  # the output's position RMSE in the air


def _fly(name: str, seed: int, *extra: str) -> NavMetrics:
    return nav_metrics(run_nav(nav_builtin(name, [*SHORT, *extra]), seed))


@pytest.mark.parametrize("seed", SEEDS)
def test_the_slam_pose_holds_the_ekf_where_the_imu_alone_drifts(seed: int) -> None:
    slam = _fly("indoor_slam", seed, "vio.camera_rate_hz=10")
    # the same flight and IMU, the odometry's heading fused but not its position
    imu = _fly("indoor_vio_odometry", seed, "vio.fuse=[yaw]")
    assert slam.vio_counts["failures"] == 0, slam.vio_events
    assert slam.vio_counts["states"] >= 0.9 * slam.vio_counts["frames"]
    assert isinstance(slam.output_rmse_m, float) and isinstance(imu.output_rmse_m, float)
    assert slam.output_rmse_m < BOUND_M < imu.output_rmse_m
    # the SLAM's samples were fused, not refused
    vio = slam.sources["vio"]
    assert vio.fused >= 0.95 * vio.received > 0
