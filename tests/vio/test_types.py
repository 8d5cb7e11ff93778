"""The VIO's state as PX4 external odometry: the covariance goes to the world frame."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import SampleError
from quadnav.geometry import Pose
from quadnav.messages import OdometrySample
from quadnav.odometry import OdometryState


def _state(yaw_deg: float, cov_pose: np.ndarray) -> OdometryState:
    R = Rotation.from_euler("z", yaw_deg, degrees=True)
    return OdometryState(
        t_ns=5,
        T_W_B=Pose(R_A_B=R, p_A_B=np.array([1.0, 2.0, 3.0])),
        v_W_B=np.array([0.1, 0.0, 0.0]),
        gyro_bias=np.zeros(3),
        accel_bias=np.zeros(3),
        cov_pose=cov_pose,
        cov_v=np.eye(3) * 0.01,
        reset_counter=2,
    )


def test_body_forward_uncertainty_is_world_north_when_facing_north() -> None:
    # GTSAM order (rx, ry, rz, x, y, z): 1 m^2 along the body's x, 0.04 rad^2 about its x axis
    cov = np.diag([0.04, 1e-4, 1e-4, 1.0, 1e-4, 1e-4])
    odo = _state(90.0, cov).odometry()
    assert odo.cov_pose[1, 1] == pytest.approx(1.0)  # world y (north) position
    assert odo.cov_pose[0, 0] == pytest.approx(1e-4)
    assert odo.cov_pose[4, 4] == pytest.approx(0.04)  # rotation about world y
    assert odo.cov_pose[3, 3] == pytest.approx(1e-4)
    assert odo.reset_counter == 2 and odo.source == "vio"
    assert np.allclose(odo.p_W_B, [1.0, 2.0, 3.0])


def test_odometry_sample_refuses_a_covariance_that_is_not_positive_definite() -> None:
    good = _state(0.0, np.eye(6) * 1e-2).odometry()
    bad = np.eye(6)
    bad[2, 2] = -1.0
    with pytest.raises(SampleError, match="cov_pose"):
        OdometrySample(
            t_ns=1, p_W_B=good.p_W_B, q_W_B_xyzw=good.q_W_B_xyzw, v_W_B=good.v_W_B,
            cov_pose=bad, cov_v=good.cov_v,
        )  # fmt: skip
    with pytest.raises(SampleError, match="quality"):
        OdometrySample(
            t_ns=1, p_W_B=good.p_W_B, q_W_B_xyzw=good.q_W_B_xyzw, v_W_B=good.v_W_B,
            cov_pose=good.cov_pose, cov_v=good.cov_v, quality=101,
        )  # fmt: skip
