"""The dataset maker's set-up in bounded memory (issue 22, item 9): the built-in flight, the
rig's body motion fitted again from 1 kHz poses and the IMU are computed a chunk at a time, and
give what they gave in one piece, to floating-point round-off."""

from __future__ import annotations

import dataclasses
import gc
import tracemalloc

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import quadnav.experiments.dataset_motions as dataset_motions
import quadnav.sim.motion as motion_module
from quadnav.experiments import datasets
from quadnav.geometry.trajectory import Trajectory
from quadnav.sim.motion import SplineMotion, synthesize_imu
from quadnav.units import s_to_ns


def _spec(duration_s: float, sensors: str = "realistic") -> datasets.SequenceSpec:
    fields = {"rig": "euroc", "seed": 4, "sensors": sensors, "duration_s": duration_s}
    return datasets.sequence_spec("room_medium", fields)


def _one_piece_body_motion(motion: SplineMotion, spec: datasets.SequenceSpec) -> SplineMotion:
    """The rig's body motion as it was made before: all the 1 kHz poses at once, one fit."""
    T_V_B = datasets.resolve_rig(spec.rig).T_V_B
    t = np.arange(motion.t_start_ns, motion.t_end_ns, s_to_ns(0.001), dtype=np.int64)
    p, q = motion.pose(t)
    R_W_V = Rotation.from_quat(q)
    traj = Trajectory(
        t_ns=t, p_W_B=p + R_W_V.apply(T_V_B.p_A_B), q_W_B_xyzw=(R_W_V * T_V_B.R_A_B).as_quat()
    )
    return SplineMotion.fit(traj, knot_spacing_s=motion.knot_spacing_s, trim_s=0.0)


def test_the_body_motion_fitted_in_chunks_is_the_one_piece_fit() -> None:
    spec = _spec(20.0)
    vehicle = datasets._motion(spec)
    T_V_B = datasets.resolve_rig(spec.rig).T_V_B
    assert not np.allclose(T_V_B.matrix(), np.eye(4))  # the rig is turned: a refit happens
    old, new = _one_piece_body_motion(vehicle, spec), datasets._rig_body_motion(vehicle, T_V_B)
    assert (new.t_start_ns, new.t_end_ns) == (old.t_start_ns, old.t_end_ns)
    t = old.t_start_ns + np.arange(5001, dtype=np.int64) * ((old.t_end_ns - old.t_start_ns) // 5000)
    for a, b in zip(old.pose(t), new.pose(t), strict=True):
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-12)
    imu_old = synthesize_imu(old, rate_hz=200.0, noise=None)
    imu_new = synthesize_imu(new, rate_hz=200.0, noise=None)
    np.testing.assert_allclose(imu_new.gyro_rad_s, imu_old.gyro_rad_s, rtol=0, atol=1e-9)
    np.testing.assert_allclose(imu_new.accel_m_s2, imu_old.accel_m_s2, rtol=0, atol=1e-9)


@pytest.mark.parametrize("sensors", ["ideal", "realistic"])
def test_a_datasets_imu_and_truth_in_chunks_are_those_in_one_piece(
    sensors: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The whole set-up with chunks of 1,000 rows against chunks longer than the dataset (the
    computation in one piece, as before): the same IMU, biases and ground truth."""
    spec = _spec(12.0, sensors)

    def made() -> tuple[list[np.ndarray], list[np.ndarray]]:
        plan = datasets.plan_dataset(spec)
        imu = datasets.synthesize_dataset_imu(plan, spec.seed)
        ds = datasets.rendered_dataset(spec, scale=0.25)
        truth = ds.groundtruth.trajectory if ds.groundtruth is not None else None
        assert truth is not None
        exact = [imu.t_ns, ds.imu.t_ns, truth.t_ns, np.array([f.t_ns for f in ds.frames])]
        return exact, [
            imu.gyro_rad_s, imu.accel_m_s2, imu.gyro_bias_rad_s, imu.accel_bias_m_s2,
            ds.imu.gyro_rad_s, ds.imu.accel_m_s2, truth.p_W_B, truth.q_W_B_xyzw,
        ]  # fmt: skip

    monkeypatch.setattr(motion_module, "CHUNK_ROWS", 10**9)
    monkeypatch.setattr(dataset_motions, "CHUNK", 10**9)
    exact_one, float_one = made()
    monkeypatch.setattr(motion_module, "CHUNK_ROWS", 1000)
    monkeypatch.setattr(dataset_motions, "CHUNK", 1000)
    exact_chunked, float_chunked = made()
    for a, b in zip(exact_one, exact_chunked, strict=True):
        np.testing.assert_array_equal(b, a)
    for a, b in zip(float_one, float_chunked, strict=True):
        assert a.shape == b.shape
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-9)


def test_the_body_motion_of_four_minutes_is_fitted_in_under_20_mb() -> None:
    """240,000 poses at 1 kHz in one piece: arrays of ~130 bytes a pose at once (the poses,
    their rotations, the fit's copies), over 30 MB here and ~500 MB for 30 minutes."""
    spec = _spec(240.0, "ideal")
    vehicle = datasets._motion(spec)
    T_V_B = datasets.resolve_rig(spec.rig).T_V_B
    tracemalloc.start()
    try:
        datasets._rig_body_motion(vehicle, T_V_B)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20e6, f"{peak / 1e6:.1f} MB"


def test_the_imu_of_four_minutes_is_synthesized_in_little_more_than_its_output(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """48,000 samples (200 Hz): the output is 6 arrays of 24 bytes a row or 8; on top, the
    white noise drawn (2 arrays of 24) and one chunk's temporaries. In one piece, the spline's
    derivatives and the errors' copies added ~15 arrays of 24 bytes a row (17 MB here)."""
    monkeypatch.setattr(motion_module, "CHUNK_ROWS", 4096)
    spec = _spec(240.0, "ideal")
    plan = datasets.plan_dataset(spec)
    tracemalloc.start()
    try:
        imu = datasets.synthesize_dataset_imu(plan, spec.seed)
        kept, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    above = peak - kept
    assert above < 3 * 24 * len(imu) + 2e6, f"{above / 1e6:.1f} MB above the output"


def test_a_rendered_datasets_frames_cost_under_300_bytes_each() -> None:
    """What a rendered dataset's frames hold (measured as what letting them go frees, the
    renderer kept alive by one of them): a ``partial`` loader and a string of its own each
    took ~470 bytes a frame (17 MB for 30 minutes at 20 Hz)."""
    spec = _spec(60.0, "ideal").model_copy(update={"rig": "euroc_mono"})
    tracemalloc.start()  # before: only what it traces, it sees freed
    try:
        ds = datasets.rendered_dataset(spec, scale=0.25)
        first, n = ds.frames[0], len(ds.frames)
        gc.collect()
        before = tracemalloc.get_traced_memory()[0]
        ds = dataclasses.replace(ds, frames=(first,))
        gc.collect()
        freed = before - tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert first.image().shape == (120, 188)  # the renderer is still there
    per_frame = freed / (n - 1)
    assert per_frame < 300, f"{per_frame:.0f} bytes a frame"
