"""The front end's keyframe decision (VINS' addFeatureCheckParallax) on synthetic tracks, and
the feature manager's bookkeeping."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.odometry import FrameFeatures
from quadnav.rig import rig_named
from quadnav.vio.config import VioConfig
from quadnav.vio.frontend import FeatureManager, Frontend, mean_parallax, normalised
from quadnav.vision.tracker_config import TrackerConfig


def _frame(t_ns: int, pts_W: np.ndarray, R_W_C: np.ndarray, p_W_C: np.ndarray) -> FrameFeatures:
    p_C = (pts_W - p_W_C) @ R_W_C
    xy = p_C[:, :2] / p_C[:, 2:3]
    return FrameFeatures(
        t_ns=t_ns, ids=np.arange(len(pts_W), dtype=np.int64), uv_px=xy * 460.0, xy=xy,
        velocity_xy_s=np.zeros_like(xy),
    )  # fmt: skip


def _scene(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform([-2.0, -1.5, 3.0], [2.0, 1.5, 6.0], size=(100, 3))


def _frontend() -> Frontend:
    return Frontend(rig_named("euroc_mono").cameras[0].camera, VioConfig())


def test_first_frame_is_a_keyframe() -> None:
    fe = _frontend()
    f = _frame(0, _scene(0), np.eye(3), np.zeros(3))
    assert fe.decide(f).keyframe


def test_pure_rotation_is_no_keyframe_once_compensated() -> None:
    """8 degrees of yaw moves the features ~60 px; the gyro's rotation explains all of it."""
    pts = _scene(1)
    fe = _frontend()
    f0 = _frame(0, pts, np.eye(3), np.zeros(3))
    fe.mark_keyframe(f0)
    R = Rotation.from_euler("y", 8.0, degrees=True).as_matrix()
    f1 = _frame(50_000_000, pts, R, np.zeros(3))
    raw = fe.decide(f1)
    comp = fe.decide(f1, R_kf_cur=R)
    assert raw.keyframe and raw.parallax_px > 30.0
    assert not comp.keyframe and comp.parallax_px < 0.01


def test_translation_is_a_keyframe_and_a_small_one_is_not() -> None:
    pts = _scene(2)
    fe = _frontend()
    f0 = _frame(0, pts, np.eye(3), np.zeros(3))
    fe.mark_keyframe(f0)
    small = fe.decide(_frame(50_000_000, pts, np.eye(3), np.array([0.01, 0.0, 0.0])), np.eye(3))
    big = fe.decide(_frame(50_000_000, pts, np.eye(3), np.array([0.15, 0.0, 0.0])), np.eye(3))
    assert not small.keyframe and small.parallax_px < 10.0
    assert big.keyframe and big.parallax_px >= 10.0


def test_too_few_tracked_or_too_long_makes_a_keyframe() -> None:
    pts = _scene(3)
    fe = _frontend()
    fe.mark_keyframe(_frame(0, pts, np.eye(3), np.zeros(3)))
    few = _frame(50_000_000, pts[:10], np.eye(3), np.zeros(3))
    assert fe.decide(few).keyframe and fe.decide(few).common == 10
    late = _frame(600_000_000, pts, np.eye(3), np.zeros(3))
    assert fe.decide(late).keyframe


def test_mean_parallax_uses_common_ids_only() -> None:
    xy = np.array([[0.0, 0.0], [0.1, 0.1]])
    par, n = mean_parallax(
        np.array([1, 2]), xy, np.array([2, 3]), np.array([[0.1, 0.2], [5.0, 5.0]])
    )
    assert n == 1 and abs(par - 0.1) < 1e-12


def test_normalised_inverts_the_camera_matrix() -> None:
    cam = rig_named("euroc_mono").cameras[0].camera
    xy = np.array([[0.1, -0.2], [-0.3, 0.05]])
    px = xy * [cam.fx, cam.fy] + cam.K[:2, 2]
    assert np.allclose(normalised(cam, px), xy)


def test_feature_manager_forgets_a_keyframe() -> None:
    fm = FeatureManager()
    f = _frame(0, _scene(4)[:3], np.eye(3), np.zeros(3))
    fm.add(0, f)
    fm.add(1, FrameFeatures(t_ns=1, ids=np.array([0], np.int64), uv_px=np.zeros((1, 2)),
                            xy=np.zeros((1, 2)), velocity_xy_s=np.zeros((1, 2))))  # fmt: skip
    fm.drop_keyframe(0)
    assert list(fm.tracks) == [0] and list(fm.observations(0)) == [1]


def test_the_vios_tracker_detects_only_when_enough_are_missing_and_stays_near_full() -> None:
    """The VIO's default ``detect_min_new`` (20): on a pan of 9 px a frame (features leave the
    image every frame), a frame that detects nothing still holds more than 130 of its 150
    features, a few frames detect (5 of 23; with VINS' 1 all 23 do), and the mean stays near
    the full 150 (140; 150 with VINS' 1)."""
    from quadnav.vision.tracking import FeatureTracker
    from tests.vision.tracking_scenes import canvas, view

    cfg = VioConfig().tracker
    assert cfg.detect_min_new == 20 and cfg.max_features == 150
    tex = canvas(np.random.default_rng(2))
    tracker = FeatureTracker(cfg)
    frames = []
    for k in range(24):
        D = np.array([[1.0, 0.0, 9.0 * k], [0.0, 1.0, -5.0 * k], [0.0, 0.0, 1.0]])
        frames.append(tracker.track(k * 50_000_000, view(tex, D)))
    later = frames[1:]
    for f in later:
        assert f.counts.new > 0 or len(f) > cfg.max_features - cfg.detect_min_new
    detecting = sum(f.counts.new > 0 for f in later)
    assert 3 <= detecting <= 0.5 * len(later)
    assert np.mean([len(f) for f in later]) >= 135


def test_a_partial_tracker_setting_keeps_the_vios_own_tracker_defaults() -> None:
    """``--set tracker.max_features=200`` changes that key only: the VIO's corner detection
    (once 20 are missing) stays, where it had fallen back to the standalone tracker's (every
    frame) as the section was rebuilt from the given keys; and in ``quadnav run``, setting a
    tracker key to its documented default is no change."""
    from quadnav.experiments.nav_config import NavScenario
    from quadnav.io.config import load_config

    vio_default = VioConfig().tracker
    c = load_config(VioConfig, None, ["tracker.max_features=200"])
    assert c.tracker.max_features == 200
    assert c.tracker.detect_min_new == vio_default.detect_min_new != TrackerConfig().detect_min_new
    same = load_config(NavScenario, None, [f"vio.tracker.max_features={vio_default.max_features}"])
    assert same.vio.tracker == vio_default
