"""The sliding window on a synthetic scene: exact landmarks on a room's walls, noisy pixels,
EuRoC-grade IMU noise; it must recover the trajectory over seeds."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest

from quadnav.eval.align import yaw_translation
from quadnav.geometry import Pose
from quadnav.geometry.camera import PinholeCamera
from quadnav.vio.config import VioConfig
from quadnav.vio.frontend import FeatureManager, normalised
from quadnav.vio.preintegration import imu_params, preintegrate
from quadnav.vio.window import FactorHook, Keyframe, SlidingWindow, StatePrior, state_keys
from tests.vio.synthetic import Scene, make_scene


def _run_window(
    scene: Scene,
    config: VioConfig,
    nees: list[float] | None = None,
    *,
    prior_cov_pose: np.ndarray | None = None,
    cov_W: list[np.ndarray] | None = None,
    hook: FactorHook | None = None,
    T_B_C_told: Pose | None = None,
    drop_from: int | None = None,
    cameras: tuple[PinholeCamera, ...] = (),
) -> tuple[np.ndarray, np.ndarray, SlidingWindow]:
    """Every frame a keyframe; the first state true (``prior_cov_pose`` its prior, 1e-6 by
    default), the rest predicted by the IMU; ``cov_W`` gets the newest pose's covariance in the
    world frame ((rot, trans), 6x6) after each solve."""
    rig = scene.rig
    assert rig.imu is not None
    params = imu_params(rig.imu.noise, g_norm=9.80665)
    told = rig.cameras[0].T_B_C if T_B_C_told is None else T_B_C_told
    win = SlidingWindow(config, told, rig.cameras[0].camera.fx, cameras=cameras)
    if hook is not None:
        win.add_hook(hook)
    fm = FeatureManager()
    t = np.array([f.t_ns for f in scene.frames])
    p, q = scene.motion.pose(t)
    v = scene.motion.velocity(t)
    from scipy.spatial.transform import Rotation

    pose0 = gtsam.Pose3(gtsam.Rot3(Rotation.from_quat(q[0]).as_matrix()), p[0])
    zero = gtsam.imuBias.ConstantBias(np.zeros(3), np.zeros(3))
    win.start(
        Keyframe(index=0, t_ns=int(t[0]), pose=pose0, velocity=v[0], bias=zero),
        StatePrior(
            cov_pose=np.eye(6) * 1e-6 if prior_cov_pose is None else prior_cov_pose,
            cov_v=np.eye(3) * 1e-4,
            cov_bias=np.diag([0.2**2] * 3 + [0.01**2] * 3),
        ),
    )
    fm.add(0, scene.frames[0])
    est = [np.asarray(pose0.translation())]
    for k in range(1, len(scene.frames)):
        prev = win.newest
        pim = preintegrate(params, scene.imu, prev.t_ns, int(t[k]), prev.bias)
        nav = pim.predict(gtsam.NavState(prev.pose, prev.velocity), prev.bias)
        win.push(
            Keyframe(index=k, t_ns=int(t[k]), pose=nav.pose(), velocity=nav.velocity(),
                     bias=prev.bias, pim=pim),
            drop_previous=drop_from is not None and k > drop_from,
        )  # fmt: skip
        fm.add(k, scene.frames[k])
        res = win.solve(fm)
        assert res.ok, res.reason
        assert len(win.keyframes) <= config.window_keyframes
        est.append(np.asarray(win.newest.pose.translation()))
        if nees is not None:  # the newest pose against the truth, in GTSAM's Pose3 tangent
            T_true = gtsam.Pose3(gtsam.Rot3(Rotation.from_quat(q[k]).as_matrix()), p[k])
            xi = gtsam.Pose3.Logmap(win.newest.pose.between(T_true))
            nees.append(float(xi @ np.linalg.solve(res.cov_pose, xi)))
        if cov_W is not None:
            J = np.kron(np.eye(2), win.newest.pose.rotation().matrix())
            cov_W.append(J @ res.cov_pose @ J.T)
    return p, np.array(est), win


@pytest.mark.parametrize(("seed", "smoother"), [(0, "isam2"), (1, "isam2"), (2, "batch")])
def test_window_recovers_the_trajectory(seed: int, smoother: str) -> None:
    """Posyaw ATE of the newest keyframe's position over 6 s (~5 m travelled) under 5 cm,
    with either smoother."""
    scene = make_scene(seed)
    nees: list[float] = []
    true_p, est_p, win = _run_window(scene, VioConfig(smoother=smoother), nees)
    R, t = yaw_translation(est_p, true_p)
    err = np.linalg.norm(R.apply(est_p) + t - true_p, axis=1)
    ate = float(np.sqrt(np.mean(err**2)))
    travelled = float(np.linalg.norm(np.diff(true_p, axis=0), axis=1).sum())
    assert travelled > 3.0
    assert ate < 0.05, f"seed {seed}: ATE {ate:.3f} m"
    assert len(win.landmarks) > 10
    # landmarks kept are near the room's walls (in the estimate's world, drift included)
    errs = [np.linalg.norm(p - scene.landmarks_W[j]) for j, p in win.landmarks.items()]
    assert float(np.median(errs)) < 0.5
    # the marginal covariance is consistent: the 6-DoF NEES averages near 6 (the pixels'
    # noise is 0.7 px, the model's 1 px: somewhat below), never many times over
    mean_nees = float(np.mean(nees[10:]))
    assert 1.0 < mean_nees < 18.0, f"seed {seed}: mean NEES {mean_nees:.1f}"


def test_yaw_uncertainty_never_drops_below_the_first_state_s() -> None:
    """Yaw is unobservable to a VIO: nothing the window sees can make the newest state's yaw
    better known than the first state's prior (0.01 rad here). A track going on after its
    landmark was marginalised used to get a prior at its old world position, a second use of
    its observations that fixed the yaw (8.7 mrad after 8 s) and the position. (The
    marginalised information is not relinearised, the factors beside it are: that leaves a
    little, 1.5 %.)"""
    scene = make_scene(0, duration_s=8.0, sigma_px=1.0)
    covs: list[np.ndarray] = []
    _run_window(scene, VioConfig(), prior_cov_pose=np.eye(6) * 0.01**2, cov_W=covs)
    sigma_yaw = np.sqrt([c[2, 2] for c in covs])
    assert sigma_yaw.min() > 0.0098, f"yaw sigma down to {1e3 * sigma_yaw.min():.2f} mrad"
    sigma_p = np.sqrt([np.diag(c)[3:].min() for c in covs])
    assert sigma_p.min() > 0.0098, f"position sigma down to {1e3 * sigma_p.min():.2f} mm"


def _book_sizes(win: SlidingWindow) -> dict[str, int]:
    """What the window keeps per track or per factor: all of it must stay bounded."""
    assert win.graph is not None
    return win.book.sizes | {"factor slots": win.graph.factor_slots}


def test_the_windows_books_stay_bounded_on_a_long_run() -> None:
    """Memory of a long run: what the window keeps after 20 s of flight is no more than after
    7 s (within the scene's variation), not three times as much: tracks that ended leave every
    book (the seeds of marginalised landmarks, the verdicts on bad ones)."""
    short = _run_window(make_scene(3, duration_s=7.0), VioConfig())[2]
    long = _run_window(make_scene(3, duration_s=20.0), VioConfig())[2]
    a, b = _book_sizes(short), _book_sizes(long)
    for name in a:
        assert b[name] <= 1.6 * a[name] + 20, (name, a, b)


def test_a_hook_adds_factors_to_every_keyframe() -> None:
    """Extra factors through the hook (a GPS-like fix at each keyframe, 0.5 m east of the
    truth, 1 cm sigma) move the window's estimate there: without the hook the window stays on
    the truth (its first state's prior), with it every keyframe follows the fixes."""
    scene = make_scene(0)
    t = np.array([f.t_ns for f in scene.frames])
    shift = np.array([0.5, 0.0, 0.0])
    fixes = {int(tk): scene.motion.pose(np.array([tk]))[0][0] + shift for tk in t}
    noise = gtsam.noiseModel.Isotropic.Sigma(3, 0.01)
    calls: list[int] = []

    def gps(kf: Keyframe) -> list[gtsam.NonlinearFactor]:
        calls.append(kf.index)
        return [gtsam.GPSFactor(state_keys(kf.index)[0], fixes[kf.t_ns], noise)]

    loose = np.diag([1e-4] * 3 + [0.01] * 3)
    true_p, est_p, _ = _run_window(scene, VioConfig(), prior_cov_pose=loose, hook=gps)
    assert calls == list(range(len(scene.frames)))
    off = est_p - true_p
    assert np.all(np.abs(off[5:] - shift).max(axis=1) < 0.05), np.abs(off - shift).max()
    _, plain, _ = _run_window(scene, VioConfig(), prior_cov_pose=loose)
    assert np.abs(plain - true_p).max() < 0.2


def _ate(est_p: np.ndarray, true_p: np.ndarray) -> float:
    R, t = yaw_translation(est_p, true_p)
    return float(np.sqrt(np.mean(np.linalg.norm(R.apply(est_p) + t - true_p, axis=1) ** 2)))


def test_the_extrinsic_told_wrong_is_refined_online() -> None:
    """The window told a camera-IMU extrinsic 0.6 degrees and 5 mm off (a realistic
    calibration error): refining it online (the default) brings the rotation at least
    half-way back to the truth and keeps the trajectory better than trusting it, over three
    seeds."""
    from scipy.spatial.transform import Rotation

    errors: dict[bool, list[float]] = {True: [], False: []}
    trusting = VioConfig(estimate_extrinsic=False, estimate_intrinsics=False)
    for seed in (0, 1, 2):
        scene = make_scene(seed)
        true = scene.rig.cameras[0].T_B_C
        off = Pose(Rotation.from_rotvec(np.radians([0.35, -0.35, 0.35])), np.array([0.005, 0, 0]))
        for online in (True, False):
            cfg = VioConfig() if online else trusting
            true_p, est_p, win = _run_window(scene, cfg, T_B_C_told=true @ off)
            errors[online].append(_ate(est_p, true_p))
            left = (true.inverse() @ win.extrinsic).R_A_B.magnitude()
            if online:
                assert left < 0.5 * off.R_A_B.magnitude(), (seed, np.degrees(left))
            else:
                assert left > 0.9 * off.R_A_B.magnitude()
    assert np.mean(errors[True]) < np.mean(errors[False]), errors


def test_intrinsics_told_wrong_are_refined_online() -> None:
    """Observations normalised with a focal length 1.5 % too long in x and 1 % too short in y,
    and a principal point off (a realistic calibration error): the window's correction finds
    the x focal within 0.5 % (the y one at least a third of the way, a shorter baseline of
    motion across it) and the trajectory is better than trusting them, over three seeds."""
    want = np.array([1 / 1.015, 1 / 0.99])
    errors: dict[bool, list[float]] = {True: [], False: []}
    for seed in (0, 1, 2):
        scene = make_scene(seed, duration_s=10.0)
        frames = [
            dataclasses.replace(f, xy=np.asarray(f.xy) * want + np.array([0.003, -0.002]))
            for f in scene.frames
        ]
        told = dataclasses.replace(scene, frames=frames)
        for online in (True, False):
            true_p, est_p, win = _run_window(told, VioConfig(estimate_intrinsics=online))
            errors[online].append(_ate(est_p, true_p))
            fx, fy = win.K_fix[0].fx(), win.K_fix[0].fy()
            if online:
                assert abs(fx - want[0]) < 0.005, (seed, fx)
                assert abs(fy - want[1]) < (2 / 3) * abs(1 - want[1]), (seed, fy)
                # its sigma (what calibration.json reports, in px) holds the x focal's error
                stated = scene.rig.cameras[0].camera
                _, sig = win.calibration_sigmas(0, stated)
                assert sig is not None and sig[0] < 0.02 * stated.K[0, 0], sig
                assert abs(fx - want[0]) * stated.K[0, 0] < 3.0 * sig[0], (seed, fx, sig)
            else:
                assert max(abs(fx - 1), abs(fy - 1)) < 1e-3  # held as stated
    assert np.mean(errors[True]) < np.mean(errors[False]), errors


@pytest.mark.slow  # a render and a run; test_intrinsics_told_wrong_are_refined_online in CI
def test_intrinsics_told_wrong_behind_a_strong_lens_are_refined_through_it() -> None:
    """EuRoC's lens (k1 = -0.28) and intrinsics told 1.3 % short in x, 1 % long in y and 2 px
    off in the principal point (realistic seed 0's draw). The front end undistorts with the
    told intrinsics, so no correction of the normalised coordinates fits the error (up to
    3 px at the corners): refined on the raw pixels through the lens model, the window finds
    both focal lengths within 0.5 % and its trajectory is better than with the correction
    after undistortion, over three seeds."""
    dist = np.array([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05])
    errors: dict[str, list[float]] = {"lens": [], "affine": [], "lens_z": []}
    for seed in (0, 1, 2):
        scene = make_scene(seed, duration_s=10.0, sigma_px=0.5)
        cam = scene.rig.cameras[0].camera
        true = PinholeCamera(cam.K, dist, cam.width, cam.height)
        K = cam.K.copy()
        K[0, 0] *= 1 - 0.0132
        K[1, 1] *= 1 + 0.0101
        K[:2, 2] += [-2.0, 0.8]
        told_cam = PinholeCamera(K, dist, cam.width, cam.height)
        frames = []
        for f in scene.frames:
            px = true.project(np.column_stack([f.xy, np.ones(len(f.xy))]))
            xy = normalised(told_cam, told_cam.undistort_pixels(px))
            frames.append(dataclasses.replace(f, xy=xy, uv_px=px))
        told = dataclasses.replace(scene, frames=frames)
        for name, cams in (("lens", (told_cam,)), ("affine", ())):
            true_p, est_p, win = _run_window(told, VioConfig(), cameras=cams)
            errors[name].append(_ate(est_p, true_p))
            fx, fy, cx, cy = win.intrinsics(0, told_cam)  # what calibration.json reports
            _, sig = win.calibration_sigmas(0, told_cam)
            assert sig is not None
            # the prior's 2 % of the focal length (9 px) and 3 px, narrowed by the views
            assert (sig[:2] < 0.02 * K[[0, 1], [0, 1]]).all() and (sig[2:] < 3.0).all(), sig
            if name == "lens":
                k = win.K_lens[0]
                assert abs(k.fx() / cam.K[0, 0] - 1) < 0.005, (seed, k.fx())
                assert abs(k.fy() / cam.K[1, 1] - 1) < 0.005, (seed, k.fy())
                assert (fx, fy, cx, cy) == (k.fx(), k.fy(), k.px(), k.py())
                z = (np.array([fx, fy, cx, cy]) - cam.K[[0, 1, 0, 1], [0, 1, 2, 2]]) / sig
                errors["lens_z"].extend(z.tolist())
            else:  # the stated pixels of a point where the refined intrinsics put it
                xs = np.array([[-0.4, -0.3], [0.0, 0.0], [0.5, 0.35]])  # stated normalised
                u = xs * [K[0, 0], K[1, 1]] + K[:2, 2]
                xr = win.corrected_xy(xs)
                np.testing.assert_allclose(xr * [fx, fy] + [cx, cy], u, atol=1e-3)
                assert abs(fx / cam.K[0, 0] - 1) < 0.0132, (seed, fx)  # nearer than told (1.3 %)
    assert np.mean(errors["lens"]) < 0.8 * np.mean(errors["affine"]), errors
    # the sigmas calibration.json reports hold the errors: 0.44 of them RMS here
    z = np.array(errors["lens_z"])
    assert np.sqrt(np.mean(z**2)) < 1.5 and np.abs(z).max() < 3.0, z


def test_dropping_the_previous_newest_keeps_the_older_keyframes() -> None:
    """From keyframe 20 on, each new keyframe has the previous newest marginalised instead of
    the oldest (VINS' MARGIN_SECOND_NEW, for keyframes made by time in a hover): the window
    keeps the keyframes it had, plus the newest, and the trajectory stays as good."""
    scene = make_scene(1)
    cfg = VioConfig()
    true_p, est_p, win = _run_window(scene, cfg, drop_from=20)
    n = len(scene.frames)
    kept = [kf.index for kf in win.keyframes]
    assert kept == list(range(20 - cfg.window_keyframes + 1, 20)) + [n - 1], kept
    _, plain_p, _ = _run_window(scene, cfg)
    assert _ate(est_p, true_p) < max(0.05, 1.5 * _ate(plain_p, true_p))


def _cal(fx: float, fy: float, u0: float, v0: float) -> gtsam.Cal3DS2:
    return gtsam.Cal3DS2(fx, fy, 0.0, u0, v0, -0.28, 0.07, 2e-4, 2e-5)


def test_a_stereo_pairs_intrinsics_move_together_and_keep_their_stated_difference() -> None:
    """Two cameras' intrinsics, each with a loose prior around what is stated (2 %, 3 px),
    and the data pulling the first camera's focal length 1 % up and its principal point 2 px
    over: tied, the second follows by at least 95 % of that (its own prior pulls it back by
    the ratio of the variances, 0.5^2 / 3^2); untied, it stays where it was stated. The tie's Jacobians are the
    numerical ones."""
    from gtsam.symbol_shorthand import K

    from quadnav.vio.window import pair_intrinsics_factor

    s0, s1 = _cal(460.0, 458.0, 370.0, 250.0), _cal(458.0, 456.5, 381.0, 255.0)
    gap = (np.asarray(s1.vector()) - np.asarray(s0.vector()))[[0, 1, 3, 4]]
    loose = gtsam.noiseModel.Diagonal.Sigmas(np.array([9.2, 9.2, 1e-4, 3, 3] + [1e-4] * 4))
    data = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.5, 0.5, 1e3, 0.2, 0.2] + [1e3] * 4))
    pulled = _cal(464.6, 458.0, 372.0, 250.0)

    def solve(tied: bool) -> tuple[gtsam.Cal3DS2, gtsam.Cal3DS2]:
        g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for key, stated in ((K(0), s0), (K(1), s1)):
            v.insert(key, stated)
            g.add(gtsam.PriorFactorCal3DS2(key, stated, loose))
        g.add(gtsam.PriorFactorCal3DS2(K(0), pulled, data))
        if tied:
            sig = np.array([0.002 * 460, 0.002 * 458, 0.5, 0.5])
            g.add(pair_intrinsics_factor(K(0), K(1), gap, sig, gtsam.Values.atCal3DS2))
        est = gtsam.LevenbergMarquardtOptimizer(g, v).optimize()
        return est.atCal3DS2(K(0)), est.atCal3DS2(K(1))

    a, b = solve(tied=True)
    assert a.fx() > 463.0 and a.px() > 371.5  # the data moved the first camera
    assert b.fx() - s1.fx() > 0.95 * (a.fx() - s0.fx())
    assert b.px() - s1.px() > 0.95 * (a.px() - s0.px())
    assert abs((b.py() - a.py()) - (s1.py() - s0.py())) < 0.01  # (nothing pulled it)
    _, b_free = solve(tied=False)
    assert abs(b_free.fx() - s1.fx()) < 0.01 and abs(b_free.px() - s1.px()) < 0.01
    # the Jacobians against central differences in each calibration's local coordinates
    f = pair_intrinsics_factor(K(0), K(1), gap, np.ones(4), gtsam.Values.atCal3DS2)
    v = gtsam.Values()
    v.insert(K(0), _cal(461.0, 457.0, 369.0, 251.0))
    v.insert(K(1), _cal(457.5, 457.0, 382.0, 254.0))
    jac = f.linearize(v).jacobian()[0]  # whitened (sigmas 1): [H0 | H1]
    for col, (key, cal) in enumerate(((K(0), v.atCal3DS2(K(0))), (K(1), v.atCal3DS2(K(1))))):
        for j in range(9):
            d = np.zeros(9)
            d[j] = 1e-4
            up, down = gtsam.Values(v), gtsam.Values(v)
            up.update(key, cal.retract(d))
            down.update(key, cal.retract(-d))
            num = (f.unwhitenedError(up) - f.unwhitenedError(down)) / 2e-4
            assert np.allclose(jac[:, 9 * col + j], num, atol=1e-6)
