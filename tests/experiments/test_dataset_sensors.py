"""``dataset make``'s sensor profiles: realistic by default (IMU turn-on biases from the rig's
spread, in-flight IMU noise while ``imu0/sensor.yaml`` states the datasheet's, an unstated
camera-IMU time offset, a calibration error in ``cam*/sensor.yaml`` with the truth in ``truth/``,
exposure and lighting changes for motion files), ideal on request; motion files' gaps bridged
within ``max_gap_s``; every setting an error advises settable."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from quadnav.errors import QuadnavError
from quadnav.experiments.datasets import (
    make_dataset,
    plan_dataset,
    sequence_spec,
    synthesize_dataset_imu,
)
from quadnav.io.datasets import open_dataset
from quadnav.rig import rig_named
from quadnav.sim.motion import synthesize_imu

# Thesis 003's camera (640x480) over 1.2 s: 25 frames, cheap to render.
SMALL = {"rig": "thesis003_sim", "duration_s": 1.2, "still_s": 0.0}


def _plan(**fields: object):  # type: ignore[no-untyped-def]
    return plan_dataset(sequence_spec("room", {**SMALL, **fields}))


def test_realistic_turn_on_biases_are_drawn_within_the_rigs_spread_per_seed() -> None:
    for rig in ("euroc_mono", "thesis003_sim"):
        imu = rig_named(rig).imu
        assert imu is not None and imu.noise.gyro_bias0_sigma_rad_s > 0
        drawn = []
        for seed in (0, 1, 2):
            noise = _plan(rig=rig, seed=seed).imu_noise
            assert noise is not None
            bg, ba = np.array(noise.gyro_bias0_rad_s), np.array(noise.accel_bias0_m_s2)
            assert np.all(bg != 0.0) and np.all(ba != 0.0)
            assert np.abs(bg).max() <= 3 * imu.noise.gyro_bias0_sigma_rad_s
            assert np.abs(ba).max() <= 3 * imu.noise.accel_bias0_sigma_m_s2
            drawn.append(np.r_[bg, ba])
        assert len({tuple(d) for d in drawn}) == 3  # another seed, other biases
    # ideal: no turn-on bias, the stated noise; imu_bias0_scale=0: realistic without biases
    ideal = _plan(sensors="ideal").imu_noise
    assert ideal is not None and ideal.gyro_bias0_rad_s == ideal.accel_bias0_m_s2 == (0.0,) * 3
    assert ideal == rig_named("thesis003_sim").imu.noise  # type: ignore[union-attr]
    none = _plan(imu_bias0_scale=0.0).imu_noise
    assert none is not None and none.gyro_bias0_rad_s == (0.0,) * 3


def test_the_time_offset_is_drawn_per_seed_and_not_stated() -> None:
    offsets = []
    for seed in (0, 1, 2, 3):
        plan = _plan(seed=seed)
        true = plan.rig.cameras[0].time_offset_ns
        assert plan.stated.cameras[0].time_offset_ns == 0
        assert 2_500_000 <= abs(true) <= 5_000_000  # 2.5 to 5 ms (time_offset_error_s 5 ms)
        offsets.append(true)
    assert len(set(offsets)) == 4
    assert _plan(sensors="ideal").rig.cameras[0].time_offset_ns == 0


def test_a_realistic_dataset_states_a_perturbed_calibration_and_keeps_the_truth(
    tmp_path: Path,
) -> None:
    spec = sequence_spec("room", {**SMALL, "rig": "euroc", "duration_s": 1.0})
    made = make_dataset(spec, tmp_path / "seq")
    plan = plan_dataset(spec)
    ds = open_dataset(made.root)
    truth = open_dataset(made.root, calibration=made.root / "truth")
    assert ds.rig.camera_names == truth.rig.camera_names == ["cam0", "cam1"]  # truth/ not read
    for cam in plan.rig.cameras:
        stated, exact = ds.rig.camera(cam.name), truth.rig.camera(cam.name)
        # the truth is exact
        assert np.array_equal(exact.camera.K, cam.camera.K)
        assert np.allclose(exact.T_B_C.matrix(), cam.T_B_C.matrix(), atol=1e-12)
        assert exact.time_offset_ns == cam.time_offset_ns != 0
        # what the estimator reads is off by about the profile's sizes
        d = cam.T_B_C.inverse() @ stated.T_B_C
        angle = math.degrees(d.R_A_B.magnitude())
        assert 0.02 < angle < 2.0 and 1e-4 < np.linalg.norm(d.p_A_B) < 0.02
        focal = stated.camera.K[[0, 1], [0, 1]] / cam.camera.K[[0, 1], [0, 1]] - 1.0
        centre = stated.camera.K[[0, 1], [2, 2]] - cam.camera.K[[0, 1], [2, 2]]
        assert np.all(focal != 0.0) and np.abs(focal).max() < 0.02
        assert np.all(centre != 0.0) and np.abs(centre).max() < 4.0
        assert np.array_equal(stated.camera.dist, cam.camera.dist)
        assert stated.time_offset_ns == 0
    # the Kalibr camchain says what sensor.yaml says (the perturbed calibration)
    chain = open_dataset(made.root, calibration=made.root / "camchain.yaml")
    assert np.allclose(chain.rig.cameras[0].camera.K, ds.rig.cameras[0].camera.K)
    assert np.allclose(
        chain.rig.cameras[0].T_B_C.matrix(), ds.rig.cameras[0].T_B_C.matrix(), atol=1e-12
    )
    # the estimator is told the datasheet's IMU noise; the data has the in-flight level
    euroc = rig_named("euroc").imu
    assert euroc is not None and euroc.flight_noise is not None
    assert ds.rig.imu is not None and truth.rig.imu is not None
    assert ds.rig.imu.noise.accel_noise_density == euroc.noise.accel_noise_density
    assert truth.rig.imu.noise.accel_noise_density == euroc.flight_noise.accel_noise_density
    assert truth.rig.imu.noise.gyro_noise_density > 10 * ds.rig.imu.noise.gyro_noise_density
    exact_imu = synthesize_imu(plan.motion, rate_hz=200.0, noise=None, t_start_ns=plan.span[0],
                               t_end_ns=plan.span[1])  # fmt: skip
    gt = ds.groundtruth
    assert gt is not None and gt.gyro_bias_rad_s is not None and gt.accel_bias_m_s2 is not None
    read = np.array([s.accel_m_s2 for s in ds.imu]) - exact_imu.accel_m_s2 - gt.accel_bias_m_s2
    sigma = euroc.flight_noise.accel_noise_density * math.sqrt(200.0)
    assert np.std(read) == pytest.approx(sigma, rel=0.1)
    # the ground truth carries the drawn turn-on biases
    assert plan.imu_noise is not None
    assert np.allclose(gt.gyro_bias_rad_s[0], plan.imu_noise.gyro_bias0_rad_s)
    assert np.allclose(gt.accel_bias_m_s2[0], plan.imu_noise.accel_bias0_m_s2)


def test_the_imu_is_quieter_on_the_ground_than_in_flight() -> None:
    """Standing still for 3 s (rotors off until a second before the take-off) the IMU shows
    its level on the ground, flying its level in flight."""
    plan = plan_dataset(
        sequence_spec("room", {"rig": "euroc_mono", "duration_s": 5.0, "still_s": 3.0})
    )
    imu = synthesize_dataset_imu(plan, 0)
    exact = synthesize_imu(plan.motion, rate_hz=200.0, noise=None, t_start_ns=plan.span[0],
                           t_end_ns=plan.span[1])  # fmt: skip
    t = (imu.t_true_ns - imu.t_true_ns[0]) / 1e9  # the span starts 0.1 s into the motion
    for name, level in (("ground", plan.ground_noise), ("flight", plan.imu_noise)):
        assert level is not None
        window = (t < 1.5) if name == "ground" else (t > 3.5)
        for got, want, bias in (
            (imu.gyro_rad_s, level.gyro_noise_density, imu.gyro_bias_rad_s),
            (imu.accel_m_s2, level.accel_noise_density, imu.accel_bias_m_s2),
        ):
            noise = got - exact.gyro_rad_s if got is imu.gyro_rad_s else got - exact.accel_m_s2
            assert np.std((noise - bias)[window]) == pytest.approx(want * math.sqrt(200), rel=0.1)
    assert plan.ground_noise is not None and plan.imu_noise is not None
    assert plan.imu_noise.accel_noise_density > 3 * plan.ground_noise.accel_noise_density
    assert plan_dataset(sequence_spec("room", {**SMALL, "sensors": "ideal"})).ground_noise is None


def test_the_rotors_vibration_is_scaled_by_imu_vibration() -> None:
    """``imu_vibration`` 0 flies at the IMU's ground level, 1 at its in-flight level, and
    between them the vibration's variance scales as its square."""
    fields = {"rig": "euroc_mono", "duration_s": 5.0, "still_s": 3.0}
    full = plan_dataset(sequence_spec("room", fields))
    quiet = plan_dataset(sequence_spec("room", {**fields, "imu_vibration": 0.0}))
    half = plan_dataset(sequence_spec("room", {**fields, "imu_vibration": 0.5}))
    assert full.ground_noise is not None and full.imu_noise is not None
    assert quiet.imu_noise is not None and half.imu_noise is not None
    g, f = full.ground_noise.accel_noise_density, full.imu_noise.accel_noise_density
    assert quiet.imu_noise.accel_noise_density == pytest.approx(g)
    assert half.imu_noise.accel_noise_density**2 == pytest.approx(g**2 + 0.25 * (f**2 - g**2))
    # the turn-on biases are the same draw
    assert quiet.imu_noise.accel_bias0_m_s2 == full.imu_noise.accel_bias0_m_s2
    imu = synthesize_dataset_imu(quiet, 0)
    exact = synthesize_imu(quiet.motion, rate_hz=200.0, noise=None, t_start_ns=quiet.span[0],
                           t_end_ns=quiet.span[1])  # fmt: skip
    t = (imu.t_true_ns - imu.t_true_ns[0]) / 1e9
    noise = imu.accel_m_s2 - exact.accel_m_s2 - imu.accel_bias_m_s2
    assert np.std(noise[t > 3.5]) == pytest.approx(g * math.sqrt(200), rel=0.1)


def test_an_ideal_dataset_states_the_calibration_it_was_made_with(tmp_path: Path) -> None:
    made = make_dataset(sequence_spec("room", {**SMALL, "sensors": "ideal"}), tmp_path / "seq")
    for rel in ("mav0/cam0/sensor.yaml", "mav0/imu0/sensor.yaml", "camchain.yaml"):
        assert (made.root / rel).read_bytes() == (made.root / "truth" / rel).read_bytes()
    gt = open_dataset(made.root).groundtruth
    assert gt is not None and gt.gyro_bias_rad_s is not None and gt.accel_bias_m_s2 is not None
    assert np.abs(gt.gyro_bias_rad_s[0]).max() == 0.0 and np.abs(gt.accel_bias_m_s2[0]).max() == 0.0
    assert (made.root / "dataset.json").read_text().count('"profile": "ideal"') == 1


def _tum(path: Path, t_s: np.ndarray) -> Path:
    """A slow walk along x, turning about z, at the times ``t_s``."""
    lines = ["# t x y z qx qy qz qw"]
    for t in t_s:
        yaw = 0.2 * t
        lines.append(
            f"{100 + t:.6f} {0.5 * t:.6f} 0 1.5 0 0 {math.sin(yaw / 2):.9f} {math.cos(yaw / 2):.9f}"
        )
    path.write_text("\n".join(lines) + "\n")
    return path


def test_motion_files_take_the_profiles_exposure_and_lighting(tmp_path: Path) -> None:
    motion = str(_tum(tmp_path / "walk.txt", np.arange(0.0, 5.0, 0.05)))
    real = sequence_spec("room", {"motion": motion})
    ideal = sequence_spec("room", {"motion": motion, "sensors": "ideal"})
    assert (real.exposure_s, real.lighting) == (0.005, 0.15)  # room_medium's
    assert (ideal.exposure_s, ideal.lighting) == (0.002, 0.0)
    told = sequence_spec("room", {"motion": motion}, ["exposure_s=0.001", "lighting=0"])
    assert (told.exposure_s, told.lighting) == (0.001, 0.0)
    plan = plan_dataset(real)
    assert plan.rig.cameras[0].exposure_s == 0.005


def test_a_gap_in_a_motion_file_is_bridged_within_max_gap_s(tmp_path: Path) -> None:
    t = np.arange(0.0, 6.0, 0.05)
    gap = _tum(tmp_path / "gap.txt", t[(t < 2.0) | (t > 2.6)])  # 0.65 s without a pose
    plan = plan_dataset(sequence_spec("room", {"motion": str(gap), "rig": "thesis003_sim"}))
    p, _ = plan.motion.pose(np.array([plan.motion.t0_ns + 2_300_000_000]))
    assert p[0, 0] == pytest.approx(0.5 * 2.3, abs=0.01)  # bridged along the walk
    long_gap = _tum(
        tmp_path / "long.txt", t[(t < 2.0) | (t > 4.0)]
    )  # 2.10 s from the last pose to the next
    with pytest.raises(QuadnavError, match=r"--set max_gap_s=S") as err:
        plan_dataset(sequence_spec("room", {"motion": str(long_gap)}))
    assert "\n" not in str(err.value) and "2.10 s" in str(err.value)
    plan = plan_dataset(sequence_spec("room", {"motion": str(long_gap)}, ["max_gap_s=2.5"]))
    assert plan.span[1] - plan.span[0] > 4_000_000_000


def test_the_knot_spacing_an_error_advises_is_settable(tmp_path: Path) -> None:
    walk = str(_tum(tmp_path / "walk.txt", np.arange(0.0, 3.0, 0.05)))
    with pytest.raises(QuadnavError, match=r"raise knot_spacing_s \(--set knot_spacing_s=S\)"):
        plan_dataset(sequence_spec("room", {"motion": walk}, ["knot_spacing_s=0.01"]))
    plan = plan_dataset(sequence_spec("room", {"motion": walk}, ["knot_spacing_s=0.4"]))
    assert plan.motion.knot_spacing_s == 0.4


def _stereo_calibration_errors(seed: int) -> tuple[float, float]:
    """The realistic ``euroc`` pair of ``seed`` rectified with its stated calibration: the
    largest row difference (px) between the two images of the same point, and the median
    relative depth error its disparities give (points 1-6 m away over the image)."""
    from quadnav.vision.stereo import StereoRectifier

    plan = plan_dataset(sequence_spec("room", {"rig": "euroc", "duration_s": 3.0, "seed": seed}))
    c0, c1 = plan.rig.cameras
    rng = np.random.default_rng(1)
    uv = np.column_stack(
        [rng.uniform(60, c0.camera.width - 60, 300), rng.uniform(40, c0.camera.height - 40, 300)]
    )
    z = rng.uniform(1.0, 6.0, 300)
    K = c0.camera.K
    xy = (c0.camera.undistort_pixels(uv) - K[:2, 2]) / np.diag(K)[:2]
    T = c1.T_B_C.inverse() @ c0.T_B_C
    p_C1 = (T.R_A_B.as_matrix() @ np.column_stack([xy * z[:, None], z]).T).T + T.p_A_B
    rect = StereoRectifier(plan.stated)
    a, b = rect.rectify_points(0, uv), rect.rectify_points(1, c1.camera.project(p_C1))
    z_hat = rect.K[0, 0] * rect.baseline_m / (a[:, 0] - b[:, 0])
    return float(np.abs(a[:, 1] - b[:, 1]).max()), float(np.median(np.abs(z_hat / z - 1.0)))


def test_a_realistic_stereo_calibration_is_one_a_calibration_tool_would_accept() -> None:
    # A stereo calibration fits both cameras on the same views of its target: it can leave both
    # focal lengths 0.5 % off, not 1 % apart. Rectified with the stated calibration, the pair's
    # rows of the same point must mostly agree within 1 px (NI Vision's advice: over 1 px,
    # calibrate again) and its depths within a few per cent; drawn independently per camera
    # they were 1-8.6 px apart and 4-17 % off.
    errors = np.array([_stereo_calibration_errors(seed) for seed in range(10)])
    rows, depth = errors[:, 0], errors[:, 1]
    assert np.median(rows) < 1.0, rows
    assert np.median(depth) < 0.03, depth
    assert rows.min() > 0.05  # the pair's calibration is still off, not exact
