"""The navigation estimator as loops see it: one builder, the ground alignment, reports."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import EstimationError
from quadnav.estimation.horizon import HorizonConfig
from quadnav.estimation.layout import NAV_ERROR
from quadnav.estimation.nav_ekf import NavEkfConfig
from quadnav.estimation.nav_filter import (
    AligningNavFilter,
    AlignmentSigmas,
    InitialSigmas,
    NavFilterSetup,
    build_nav_filter,
)
from quadnav.messages import GpsSample, ImuSample, PoseSample

G = 9.80665
SETUP = NavFilterSetup(
    ekf=NavEkfConfig(datum_lla=(47.0, 8.0, 400.0)),
    horizon=HorizonConfig(imu_period_ns=4_000_000, max_delay_ns=100_000_000),
)


def _imu(t_ns: int) -> ImuSample:
    return ImuSample(t_ns=t_ns, gyro_rad_s=np.zeros(3), accel_m_s2=np.array([0.0, 0.0, G]))


def test_initial_sigmas_land_on_the_error_state_blocks() -> None:
    s = InitialSigmas(
        tilt_rad=0.1,
        yaw_rad=0.2,
        vel_m_s=0.3,
        pos_xy_m=0.4,
        pos_z_m=0.5,
        gyro_bias_rad_s=0.6,
        accel_bias_m_s2=0.7,
    )
    sd = np.sqrt(np.diag(s.P0()))
    np.testing.assert_allclose(sd[NAV_ERROR["att"]], [0.1, 0.1, 0.2])
    np.testing.assert_allclose(sd[NAV_ERROR["vel"]], [0.3] * 3)
    np.testing.assert_allclose(sd[NAV_ERROR["pos"]], [0.4, 0.4, 0.5])
    np.testing.assert_allclose(sd[NAV_ERROR["gyro_bias"]], [0.6] * 3)
    np.testing.assert_allclose(sd[NAV_ERROR["accel_bias"]], [0.7] * 3)
    with pytest.raises(EstimationError):
        InitialSigmas(vel_m_s=0.0).P0()


def test_the_builder_starts_the_filter_where_it_is_told() -> None:
    q = Rotation.from_euler("z", 0.3).as_quat()
    est = build_nav_filter(SETUP, t0_ns=5, p0=np.array([1.0, 2.0, 3.0]), q0_xyzw=q)
    d = est.delayed()
    np.testing.assert_allclose(d.p_W_B, [1, 2, 3])
    assert (Rotation.from_quat(d.q_W_B_xyzw).inv() * Rotation.from_quat(q)).magnitude() < 1e-12
    assert d.P is not None and np.allclose(d.P, SETUP.sigmas.P0())


def _pose(t_ns: int) -> PoseSample:
    return PoseSample(
        t_ns=t_ns,
        p_W_B=np.array([0.5, -0.2, 0.0]),
        q_W_B_xyzw=Rotation.from_euler("z", 0.4).as_quat(),
        sigma_pos_m=0.02,
        sigma_yaw_rad=0.05,
    )


@pytest.mark.parametrize("heading_from_pose", [True, False])
def test_alignment_levels_from_what_it_was_pushed_with_that_sources_sigmas(
    heading_from_pose: bool,
) -> None:
    f = AligningNavFilter(
        SETUP,
        align_ns=100_000_000,
        heading_from_pose=heading_from_pose,
        alignment=AlignmentSigmas(pose_factor=3.0, yaw_unknown_rad=1.5, pos_unknown_m=0.25),
    )
    for k in range(26):
        assert not f.ready
        f.push(_pose(k * 4_000_000))
        f.push(_imu(k * 4_000_000 + 1))
    assert f.ready
    d = f.delayed()
    sd = np.sqrt(np.diag(d.P))  # type: ignore[arg-type]
    yaw = Rotation.from_quat(d.q_W_B_xyzw).as_euler("ZYX")[0]
    if heading_from_pose:
        assert yaw == pytest.approx(0.4) and sd[2] == pytest.approx(0.15)
        np.testing.assert_allclose(d.p_W_B, [0.5, -0.2, 0.0])
        assert sd[NAV_ERROR["pos"]][0] == pytest.approx(0.06)
    else:  # rotated vision: nothing else observed the heading, the origin is where it stands
        assert yaw == pytest.approx(0.0) and sd[2] == pytest.approx(1.5)
        np.testing.assert_allclose(d.p_W_B, [0.0, 0.0, 0.0])
        assert sd[NAV_ERROR["pos"]][0] == pytest.approx(0.25)


def test_a_gnss_fix_places_the_aligned_filter_and_sets_its_sigma() -> None:
    f = AligningNavFilter(SETUP, align_ns=8_000_000)
    import pymap3d

    lat, lon, alt = pymap3d.enu2geodetic(10.0, -4.0, 0.0, 47.0, 8.0, 400.0)
    f.push(
        GpsSample(
            t_ns=0,
            lat_deg=lat,
            lon_deg=lon,
            alt_m=alt,
            v_enu_m_s=np.zeros(3),
            sigma_h_m=0.7,
            sigma_v_m=1.0,
            sigma_vel_m_s=0.1,
        )
    )
    for t in (4_000_000, 8_000_000):
        f.push(_imu(t))
    d = f.delayed()
    np.testing.assert_allclose(d.p_W_B, [10.0, -4.0, 0.0], atol=1e-6)
    assert np.sqrt(d.P[6, 6]) == pytest.approx(1.4)  # type: ignore[index]


def test_a_surveyed_start_places_the_filter_where_it_stands_whatever_the_gnss_says() -> None:
    """``start_pose``: the pad the vehicle aligns on, surveyed. The filter starts there (not at
    the first fix, 10.8 m off), with the heading given and the start's sigmas; roll and pitch
    are still levelled from gravity."""
    start = (2.0, 3.0, 0.5, np.radians(30.0))
    a = AlignmentSigmas(start_pose=start, start_pos_sigma_m=0.05, start_yaw_sigma_rad=0.02)
    f = AligningNavFilter(SETUP, align_ns=8_000_000, alignment=a)
    import pymap3d

    lat, lon, alt = pymap3d.enu2geodetic(10.0, -4.0, 0.0, 47.0, 8.0, 400.0)
    fix = GpsSample(
        t_ns=0, lat_deg=lat, lon_deg=lon, alt_m=alt, v_enu_m_s=np.zeros(3), sigma_h_m=0.7,
        sigma_v_m=1.0, sigma_vel_m_s=0.1,
    )  # fmt: skip
    f.push(fix)
    tilted = Rotation.from_euler("x", 0.05)  # standing 0.05 rad rolled
    for t in (4_000_000, 8_000_000):
        f.push(ImuSample(t_ns=t, gyro_rad_s=np.zeros(3), accel_m_s2=tilted.inv().apply([0, 0, G])))
    d = f.delayed()
    np.testing.assert_allclose(d.p_W_B, [2.0, 3.0, 0.5], atol=1e-9)
    yaw, _, roll = Rotation.from_quat(d.q_W_B_xyzw).as_euler("ZYX")
    assert yaw == pytest.approx(np.radians(30.0)) and roll == pytest.approx(0.05)
    sig = np.sqrt(np.diag(d.P))  # type: ignore[arg-type]
    assert sig[6] == pytest.approx(0.05) and sig[2] == pytest.approx(0.02)


def test_no_estimate_before_alignment_and_reports_are_frozen_snapshots() -> None:
    f = AligningNavFilter(SETUP, align_ns=8_000_000)
    with pytest.raises(EstimationError, match="alignment"):
        f.output()
    assert f.report().sources == {}
    for t in range(0, 40_000_001, 4_000_000):
        f.push(_pose(t))
        f.push(_imu(t + 1))
    before = f.report().sources["vision"]
    for t in range(44_000_000, 80_000_001, 4_000_000):
        f.push(_pose(t))
        f.push(_imu(t + 1))
    after = f.report().sources["vision"]
    assert after.received > before.received  # the snapshot did not move with the counters
    with pytest.raises(dataclasses.FrozenInstanceError):
        before.received = 0  # type: ignore[misc]
