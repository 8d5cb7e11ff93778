"""Gyro bias and linear alignment on exact inputs: the truth's rotations and (scaled) camera
positions with the preintegrated IMU give back the bias, the scale and gravity."""

from __future__ import annotations

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.messages import ImuSample
from quadnav.rig import ImuNoiseModel
from quadnav.units import GRAVITY_M_S2
from quadnav.vio.alignment import (
    AlignmentResult,
    corrected_deltas,
    gyro_bias_from_rotations,
    linear_alignment,
)
from quadnav.vio.preintegration import imu_params, preintegrate
from tests.vio.init_scene import Scene, make_scene


def test_deltas_under_a_new_bias_match_a_re_integration() -> None:
    rng = np.random.default_rng(4)
    samples = [
        ImuSample(
            t_ns=k * 5_000_000, gyro_rad_s=rng.normal(0, 0.5, 3), accel_m_s2=rng.normal(0, 3, 3)
        )
        for k in range(41)
    ]
    params = imu_params(ImuNoiseModel.euroc_adis16448())
    pim = preintegrate(params, samples, 0, 200_000_000)
    b = np.array([0.01, -0.02, 0.015])
    again = preintegrate(
        params, samples, 0, 200_000_000, gtsam.imuBias.ConstantBias(np.zeros(3), b)
    )
    d = corrected_deltas(pim, b)
    assert (d.dR.inv() * Rotation.from_matrix(again.deltaRij().matrix())).magnitude() < 1e-6
    assert np.allclose(d.dV, again.deltaVij(), atol=1e-5)
    assert np.allclose(d.dP, again.deltaPij(), atol=1e-6)
    # and the bias does move them: the check above is not trivially met
    assert np.linalg.norm(d.dV - pim.deltaVij()) > 1e-4


def _truth(scene: Scene) -> tuple[list[Rotation], np.ndarray]:
    """The true ``R_C0_B`` and camera positions in ``C0``."""
    T_B_C = scene.window.T_B_C
    T_W_C0 = scene.T_W_B[0] @ T_B_C
    R_C0_B = [(T_W_C0.inverse() @ T).R_A_B for T in scene.T_W_B]
    p = np.array([(T_W_C0.inverse() @ T @ T_B_C).p_A_B for T in scene.T_W_B])
    return R_C0_B, p


def test_true_rotations_give_back_the_gyro_bias() -> None:
    for seed in range(5):
        scene = make_scene(seed, gyro_bias=(0.02, -0.01, 0.005))
        R_C0_B, _ = _truth(scene)
        b = gyro_bias_from_rotations(R_C0_B, scene.window.preintegrations)
        # what bounds it is GTSAM's sample-and-hold over 5 ms steps (the rate at each step's
        # start: about the angular acceleration times 2.5 ms, ~1.5e-3 rad/s here), not the noise
        assert np.linalg.norm(b - scene.gyro_bias) < 2.5e-3


def test_true_structure_gives_back_scale_gravity_and_velocities() -> None:
    for seed in range(5):
        scene = make_scene(seed, gyro_bias=(0.0, 0.0, 0.0))
        R_C0_B, p = _truth(scene)
        deltas = [corrected_deltas(pim, np.zeros(3)) for pim in scene.window.preintegrations]
        al = linear_alignment(
            p / 2.5, R_C0_B, deltas, scene.window.T_B_C.p_A_B, g_norm=GRAVITY_M_S2
        )
        assert isinstance(al, AlignmentResult)
        assert abs(al.scale / 2.5 - 1.0) < 0.01
        g_true = (scene.T_W_B[0] @ scene.window.T_B_C).R_A_B.inv().apply([0, 0, -GRAVITY_M_S2])
        cos = al.gravity_C0 @ g_true / GRAVITY_M_S2**2
        assert np.degrees(np.arccos(min(cos, 1.0))) < 0.1
        assert abs(np.linalg.norm(al.gravity_C0) - GRAVITY_M_S2) < 1e-9
        v_true = np.array(
            [T.R_A_B.inv().apply(v) for T, v in zip(scene.T_W_B, scene.v_W_B, strict=True)]
        )
        assert np.abs(al.v_B - v_true).max() < 0.02


def test_a_mirrored_structure_is_refused() -> None:
    scene = make_scene(0, gyro_bias=(0.0, 0.0, 0.0))
    R_C0_B, p = _truth(scene)
    deltas = [corrected_deltas(pim, np.zeros(3)) for pim in scene.window.preintegrations]
    out = linear_alignment(-p, R_C0_B, deltas, scene.window.T_B_C.p_A_B, g_norm=GRAVITY_M_S2)
    assert isinstance(out, str)


def test_a_known_scale_needs_no_acceleration() -> None:
    """At constant velocity (``cruise``) the scale is not observable: the free alignment refuses;
    held at the true (stereo, metric) scale the velocities and gravity still come out."""
    for seed in range(3):
        scene = make_scene(seed, gyro_bias=(0.0, 0.0, 0.0), cruise=True)
        R_C0_B, p = _truth(scene)
        deltas = [corrected_deltas(pim, np.zeros(3)) for pim in scene.window.preintegrations]
        p_B_C = scene.window.T_B_C.p_A_B
        free = linear_alignment(p, R_C0_B, deltas, p_B_C, g_norm=GRAVITY_M_S2)
        assert isinstance(free, str) and "not observable" in free
        held = linear_alignment(p, R_C0_B, deltas, p_B_C, g_norm=GRAVITY_M_S2, scale=1.0)
        assert isinstance(held, AlignmentResult) and held.scale == 1.0
        g_true = (scene.T_W_B[0] @ scene.window.T_B_C).R_A_B.inv().apply([0, 0, -GRAVITY_M_S2])
        cos = held.gravity_C0 @ g_true / GRAVITY_M_S2**2
        assert np.degrees(np.arccos(min(cos, 1.0))) < 0.2
        v_true = np.array(
            [T.R_A_B.inv().apply(v) for T, v in zip(scene.T_W_B, scene.v_W_B, strict=True)]
        )
        assert np.abs(held.v_B - v_true).max() < 0.02
