"""The named state layouts, and that every StateEstimate's names label its values."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import EstimationError
from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig
from quadnav.estimation.layout import NAV_ERROR, NAV_NOMINAL, NAV_OUTPUT, StateLayout
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig
from quadnav.messages import ImuSample, StateEstimate

from .conftest import Flight, make_estimator


def test_blocks_name_their_entries_and_bad_layouts_are_refused() -> None:
    assert NAV_ERROR.names[NAV_ERROR["pos"]] == ("x", "y", "z")
    assert NAV_ERROR.names[NAV_ERROR["att"]] == ("dtheta_x", "dtheta_y", "dtheta_z")
    assert NAV_NOMINAL.names[NAV_NOMINAL["vel"]] == ("vx", "vy", "vz")
    assert NAV_ERROR.index("z") == NAV_ERROR["pos"].stop - 1
    assert NAV_ERROR.size == 15 and NAV_OUTPUT.size == 15
    with pytest.raises(EstimationError, match="no block 'wind'"):
        NAV_ERROR.block("wind")
    with pytest.raises(EstimationError, match="repeated"):
        StateLayout(("a", ("x",)), ("b", ("x",)))


def _by_name(est: StateEstimate) -> dict[str, float]:
    assert len(est.names) == len(est.x)
    return dict(zip(est.names, est.x.tolist(), strict=True))


def _nav_estimator() -> DelayedHorizonEstimator:
    q0 = Rotation.from_euler("ZYX", [0.7, 0.1, -0.2]).as_quat()
    ekf = NavEkf(NavEkfConfig(), p0=np.array([1.0, -2.0, 3.0]), v0=np.array([0.4, -0.5, 0.6]),
                 q0_xyzw=q0, P0=np.eye(15) * 1e-4)  # fmt: skip
    est = DelayedHorizonEstimator(
        ekf, HorizonConfig(imu_period_ns=4_000_000, max_delay_ns=40_000_000), t0_ns=0
    )
    for k in range(1, 40):
        est.push(ImuSample(t_ns=4_000_000 * k, gyro_rad_s=[0.1, -0.2, 0.3], accel_m_s2=[0.5, 0.2, 9.9]))  # fmt: skip
    return est


def test_the_nav_output_names_label_position_velocity_and_rotation() -> None:
    out = _nav_estimator().output()
    v = _by_name(out)
    np.testing.assert_allclose([v["x"], v["y"], v["z"]], out.p_W_B)
    np.testing.assert_allclose([v["vx"], v["vy"], v["vz"]], out.v_W_B)
    R = Rotation.from_quat(out.q_W_B_xyzw).as_matrix()
    for i in range(3):
        for j in range(3):
            assert v[f"R_W_B_{i}{j}"] == pytest.approx(R[i, j], abs=1e-9)


def test_the_nav_delayed_names_label_the_nominal_state() -> None:
    d = _nav_estimator().delayed()
    v = _by_name(d)
    np.testing.assert_allclose([v["x"], v["y"], v["z"]], d.p_W_B)
    np.testing.assert_allclose([v["vx"], v["vy"], v["vz"]], d.v_W_B)
    rv = Rotation.from_quat(d.q_W_B_xyzw).as_rotvec()
    np.testing.assert_allclose([v["rotvec_x"], v["rotvec_y"], v["rotvec_z"]], rv, atol=1e-9)
    assert d.P is not None and d.P.shape == (NAV_ERROR.size, NAV_ERROR.size)


def test_the_planar_output_names_label_its_values(clean_flight: Flight) -> None:
    est = make_estimator(clean_flight, max_delay_ns=50_000_000)
    for imu in clean_flight.imu[:150]:
        est.push(imu)
    out = est.output()
    v = _by_name(out)
    assert (v["x"], v["z"]) == pytest.approx((out.p_W_B[0], out.p_W_B[2]))
    assert (v["vx"], v["vz"]) == pytest.approx((out.v_W_B[0], out.v_W_B[2]))
    pitch = Rotation.from_quat(out.q_W_B_xyzw).as_rotvec()[1]
    assert v["theta"] == pytest.approx(pitch)


def _rejected_long(ekf: NavEkf, make) -> None:
    for k in range(5):  # every 0.5 s for 2 s: the last reaches reset_after_s (2 s)
        ekf.fuse(make(500_000_000 * k))


def _pose(t_ns: int):
    from quadnav.messages import PoseSample

    q = Rotation.from_euler("z", 0.5).as_quat()
    return PoseSample(t_ns=t_ns, p_W_B=[10.0, 0.0, 1.0], q_W_B_xyzw=q, sigma_pos_m=0.1, sigma_yaw_rad=0.05)  # fmt: skip


@pytest.mark.parametrize("frame", ["world", "rotate"])
def test_a_reset_touches_the_named_entries_the_observation_type_observes(frame: str) -> None:
    from quadnav.estimation.nav_ekf import yaw_of

    ekf = NavEkf(NavEkfConfig(vision_frame=frame, vision_anchor_samples=1), p0=np.zeros(3),
                 v0=np.zeros(3), q0_xyzw=[0, 0, 0, 1.0], P0=np.eye(15) * 1e-4)  # fmt: skip
    if frame == "rotate":  # anchor the frame on a first pose at the origin, then jump
        from quadnav.messages import PoseSample

        ekf.fuse(PoseSample(t_ns=0, p_W_B=np.zeros(3), q_W_B_xyzw=[0, 0, 0, 1.0], sigma_pos_m=0.1, sigma_yaw_rad=0.05))  # fmt: skip
    _rejected_long(ekf, lambda t: _pose(t + 1))
    pos, yaw = NAV_ERROR["pos"], NAV_ERROR.index("dtheta_z")
    var_p = np.diag(ekf.P)[pos]  # the pose's noise (rotated vision adds its frame's yaw error)
    assert var_p[2] == pytest.approx(0.1**2) and (var_p >= 0.1**2 - 1e-12).all()
    assert not ekf.P[pos, NAV_ERROR["vel"]].any()
    if frame == "world":  # a pose in the navigation frame: its heading is reset too
        assert yaw_of(ekf.R) == pytest.approx(0.5)
        assert ekf.P[yaw, yaw] == pytest.approx(0.05**2)
        assert "position and heading reset" in ekf.events[-1][1]
    else:  # rotated vision carries no heading: the attitude is left alone
        assert yaw_of(ekf.R) == pytest.approx(0.0)
        assert ekf.P[yaw, yaw] == pytest.approx(1e-4)
        assert ekf.events[-1][1].endswith("position reset to it")


def test_a_height_reset_touches_z_only() -> None:
    from quadnav.messages import HeightSample

    ekf = NavEkf(NavEkfConfig(), p0=np.zeros(3), v0=np.zeros(3), q0_xyzw=[0, 0, 0, 1.0],
                 P0=np.full((15, 15), 1e-6) + np.eye(15) * 1e-4)  # fmt: skip
    _rejected_long(ekf, lambda t: HeightSample(t_ns=t, z_m=5.0, sigma_m=0.2, source="height"))
    z = NAV_ERROR.index("z")
    assert ekf.p[2] == pytest.approx(5.0)
    assert ekf.P[z, z] == pytest.approx(0.04)
    others = np.delete(np.arange(15), z)
    assert not ekf.P[z, others].any() and not ekf.P[others, z].any()
    assert ekf.P[0, 1] == pytest.approx(1e-6)  # the rest is untouched
