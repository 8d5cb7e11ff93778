"""Visual-inertial initialisation for a start in motion: judged over seeded synthetic windows
(a smooth path at about 0.9 m/s, 300 points 2-10 m away, 0.5 px pixel noise, the ADIS16448's
IMU noise plus a 0.017 rad/s gyro bias) against the truth that made them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import VioError
from quadnav.vio.initialization import (
    InitFailure,
    InitSettings,
    try_visual_inertial_init,
    visual_inertial_init,
)
from quadnav.vio.types import InitResult
from tests.vio.init_scene import Scene, make_scene

SEEDS = range(5)


def _errors(scene: Scene, r: InitResult) -> tuple[float, float, float, float]:
    """Scale error (fraction), gravity direction error (deg, in the first body), gyro bias error
    (rad/s) and the largest velocity error (m/s, each in its body)."""
    truth = scene.T_W_B
    g_est = r.T_W_B[0].R_A_B.inv().apply([0.0, 0.0, -1.0])
    g_true = truth[0].R_A_B.inv().apply([0.0, 0.0, -1.0])
    angle = float(np.degrees(np.arccos(np.clip(g_est @ g_true, -1.0, 1.0))))
    p_est = np.array([T.p_A_B for T in r.T_W_B])
    p_true = np.array([T.p_A_B - truth[0].p_A_B for T in truth])
    scale = np.sum(np.linalg.norm(p_est, axis=1)) / np.sum(np.linalg.norm(p_true, axis=1))
    v_true = np.array([T.R_A_B.inv().apply(v) for T, v in zip(truth, scene.v_W_B, strict=True)])
    v_est = np.array([T.R_A_B.inv().apply(v) for T, v in zip(r.T_W_B, r.v_W_B, strict=True)])
    return (
        abs(float(scale) - 1.0),
        angle,
        float(np.linalg.norm(r.gyro_bias - scene.gyro_bias)),
        float(np.linalg.norm(v_est - v_true, axis=1).max()),
    )


def test_a_window_in_motion_gives_scale_gravity_bias_and_velocities() -> None:
    errs = []
    for seed in SEEDS:
        scene = make_scene(seed, pixel_sigma=0.5, speed=1.5)
        r = visual_inertial_init(scene.window)
        assert r is not None, f"seed {seed}: {try_visual_inertial_init(scene.window)}"
        errs.append(_errors(scene, r))
        # W: the first body at the origin with zero yaw, gravity down its z
        assert np.allclose(r.T_W_B[0].p_A_B, 0.0, atol=1e-9)
        assert abs(r.T_W_B[0].R_A_B.as_euler("ZYX")[0]) < 1e-9
        assert len(r.T_W_B) == len(scene.window.frames) and len(r.landmarks_W) > 100
    e = np.array(errs)
    assert e[:, 0].max() < 0.05  # scale within 5 %
    assert e[:, 1].max() < 2.0 and e[:, 1].mean() < 0.5  # gravity direction (deg)
    assert e[:, 2].max() < 0.006  # gyro bias (rad/s) out of a true 0.017
    assert e[:, 3].max() < 0.1  # velocities (m/s) at about 0.9 m/s


def test_landmarks_land_at_the_true_points_in_the_windows_world() -> None:
    scene = make_scene(1, pixel_sigma=0.5, speed=1.5)
    r = visual_inertial_init(scene.window)
    assert r is not None
    # the result's W is the true world turned by the first body's yaw about its position
    T0 = scene.T_W_B[0]
    R_Wr_W = Rotation.from_euler("z", -T0.R_A_B.as_euler("ZYX")[0])
    ids = np.array(sorted(r.landmarks_W))
    est = np.array([r.landmarks_W[i] for i in ids])
    true = R_Wr_W.apply(scene.points_W[ids] - T0.p_A_B)
    rel = np.linalg.norm(est - true, axis=1) / np.linalg.norm(true, axis=1)
    assert np.median(rel) < 0.05


def test_the_gyro_bias_step_improves_gravity() -> None:
    # noise-free features, so the IMU is what limits; keyframes 0.2 s apart and a 0.017 rad/s bias
    with_step, without = [], []
    for seed in SEEDS:
        scene = make_scene(seed, pixel_sigma=0.0, frame_dt_s=0.2)
        a = try_visual_inertial_init(scene.window)
        skip = InitSettings(estimate_gyro_bias=False, max_rotation_residual_deg=90.0)
        b = try_visual_inertial_init(scene.window, settings=skip)
        assert isinstance(a, InitResult) and isinstance(b, InitResult)
        with_step.append(_errors(scene, a)[1])
        without.append(_errors(scene, b)[1])
        assert _errors(scene, a)[2] < 0.002
    assert np.median(without) > 2.0 * np.median(with_step)


def test_a_pure_rotation_does_not_initialise() -> None:
    scene = make_scene(0, spin=True)
    assert visual_inertial_init(scene.window) is None
    out = try_visual_inertial_init(scene.window)
    assert isinstance(out, InitFailure) and out.stage == "sfm" and "parallax" in out.reason


def test_a_constant_velocity_leaves_the_scale_unobservable() -> None:
    # the IMU then measures gravity alone: any scale fits, so the alignment must refuse
    for seed in range(3):
        scene = make_scene(seed, pixel_sigma=0.5, cruise=True, speed=1.5)
        out = try_visual_inertial_init(scene.window)
        assert isinstance(out, InitFailure) and out.stage == "alignment", out
    # the same motion with the accelerations of the figure path initialises
    assert visual_inertial_init(make_scene(0, pixel_sigma=0.5, speed=1.5).window) is not None


def test_too_few_features_do_not_initialise() -> None:
    scene = make_scene(0, n_points=15)
    out = try_visual_inertial_init(scene.window)
    assert isinstance(out, InitFailure) and out.stage == "sfm" and "20 features" in out.reason


def test_a_malformed_window_is_refused() -> None:
    w = make_scene(0).window
    with pytest.raises(VioError, match="preintegrations"):
        visual_inertial_init(dataclasses.replace(w, preintegrations=w.preintegrations[:-1]))
    swapped = (w.frames[1], w.frames[0], *w.frames[2:])
    with pytest.raises(VioError, match="not increasing"):
        visual_inertial_init(dataclasses.replace(w, frames=swapped))
    bad = dataclasses.replace(w.frames[3], xy=np.full_like(w.frames[3].xy, np.nan))
    with pytest.raises(VioError, match="non-finite"):
        visual_inertial_init(dataclasses.replace(w, frames=(*w.frames[:3], bad, *w.frames[4:])))


def test_a_stereo_start_in_a_large_space_takes_far_points() -> None:
    """EuRoC's 0.11 m baseline in a hall whose points are all 6-14 m away (55-130 baselines,
    beyond ORB-SLAM's 40 for close points): the stereo start takes the far points and starts,
    metric, on 4 keyframes, over seeds; with 40 baselines as the limit it had refused (the
    corridor sequence started 17 s late)."""
    errs = []
    for seed in SEEDS:
        scene = make_scene(
            seed,
            n_frames=4,
            pixel_sigma=0.3,
            speed=1.5,
            depth_m=(6.0, 14.0),
            stereo_baseline_m=0.11,
        )
        out = try_visual_inertial_init(scene.window)
        assert isinstance(out, InitResult), f"seed {seed}: {out}"
        assert out.detail.startswith("stereo"), out.detail
        errs.append(_errors(scene, out))
    e = np.array(errs)
    assert e[:, 0].max() < 0.1  # metric from the pair: scale within 10 %
    assert e[:, 1].max() < 3.0  # gravity direction (deg)


def test_without_usable_stereo_points_the_start_falls_back_to_one_camera() -> None:
    """Points beyond 150 baselines (20-40 m) give no stereo depth; over a mono window's parallax
    the start from motion alone initialises and says why stereo did not; where motion cannot
    either, the refusal names both."""
    for seed in SEEDS:
        scene = make_scene(
            seed, pixel_sigma=0.5, speed=1.5, depth_m=(2.0, 10.0), stereo_baseline_m=0.11
        )
        far = dataclasses.replace(
            scene.window,
            frames=tuple(
                dataclasses.replace(f, stereo_ids=f.stereo_ids[:5], stereo_xy=f.stereo_xy[:5])
                for f in scene.window.frames
            ),
        )
        out = try_visual_inertial_init(far)
        assert isinstance(out, InitResult), f"seed {seed}: {out}"
        assert "stereo: the first frame has" in out.detail, out.detail
        assert _errors(scene, out)[0] < 0.05
    short = dataclasses.replace(far, frames=far.frames[:2], preintegrations=far.preintegrations[:1])
    refused = try_visual_inertial_init(short)
    assert isinstance(refused, InitFailure) and "(stereo: the first frame has" in refused.reason
