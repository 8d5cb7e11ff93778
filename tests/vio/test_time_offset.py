"""The online camera-IMU time offset: a wobbling rotation seen by a 200 Hz gyro (ADIS16448
noise, a 0.01 rad/s bias) and by 20 Hz camera rotations with 0.03 deg of noise, stamped ``td``
early (``t_imu = t_image + td``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import VioError
from quadnav.io.datasets import VisualInertialDataset
from quadnav.messages import ImageFrame
from quadnav.rig import euroc_mono
from quadnav.units import NS_PER_S
from quadnav.vio import VioEstimator
from quadnav.vio.config import VioConfig
from quadnav.vio.time_offset import TdEstimate, TimeOffsetEstimator
from tests.vio.rendered import rendered

R_B_C = euroc_mono().cameras[0].T_B_C.R_A_B
_H_S = 1e-4


def _attitude(t_s: np.ndarray) -> Rotation:
    eul = np.column_stack(
        [
            0.4 * np.sin(2.2 * t_s) + 0.2 * np.sin(4.3 * t_s),
            0.25 * np.sin(3.4 * t_s + 1.0),
            0.2 * np.sin(5.1 * t_s),
        ]
    )
    return Rotation.from_euler("ZYX", eul)


def _feed(
    est: TimeOffsetEstimator,
    td_s: float,
    seed: int,
    *,
    spin_only: bool = False,
    duration_s: float = 8.0,
    keyframes: bool = False,
    noise_deg: float = 0.03,
) -> None:
    """Gyro and camera rotations into ``est``: between consecutive 20 Hz images, or
    (``keyframes``) between images 2 to 6 frames apart, as a keyframe window makes them."""
    rng = np.random.default_rng(seed)
    tg = np.arange(0.0, duration_s, 0.005)
    if spin_only:  # a constant rate about one axis: nothing to align
        w = np.tile([0.0, 0.0, 0.3], (len(tg), 1))
        attitude = lambda t: Rotation.from_rotvec(np.outer(t, [0.0, 0.0, 0.3]))  # noqa: E731
    else:
        w = (_attitude(tg - _H_S / 2).inv() * _attitude(tg + _H_S / 2)).as_rotvec() / _H_S
        attitude = _attitude
    w = w + rng.normal(0.0, 1.7e-4 * np.sqrt(200.0), w.shape) + 0.01
    tc = np.arange(0.2, duration_s - 0.2, 0.05)  # the true times of the images
    R_W_B = attitude(tc)
    stamps_ns = np.rint((tc - td_s) * 1e9).astype(np.int64)
    g, prev, k = 0, 0, 1
    while k < len(tc):
        while g < len(tg) and tg[g] <= tc[k] + 0.12:
            est.push_gyro(int(np.rint(tg[g] * 1e9)), w[g])
            g += 1
        R_C0_C1 = R_B_C.inv() * (R_W_B[prev].inv() * R_W_B[k]) * R_B_C
        noise = Rotation.from_rotvec(rng.normal(0.0, np.radians(noise_deg), 3))
        est.push_rotation(int(stamps_ns[prev]), int(stamps_ns[k]), R_C0_C1 * noise)
        prev, k = k, k + (int(rng.integers(2, 7)) if keyframes else 1)


@pytest.mark.parametrize("td_s", [0.005, -0.010, 0.020])
def test_a_known_offset_is_found_within_a_millisecond(td_s: float) -> None:
    for seed in range(5):
        est = TimeOffsetEstimator(R_B_C)
        _feed(est, td_s, seed)
        e = est.estimate()
        assert isinstance(e, TdEstimate)
        assert abs(e.td_s - td_s) < 1e-3
        assert e.converged and e.sigma_s < 5e-4 and e.excited
        # the buffer keeps the last 6 s of 20 Hz spans, less the search margin
        assert 90 < e.n_rotations <= 121


def test_keyframe_spans_and_an_unknown_mount_work_too() -> None:
    for seed in range(5):
        est = TimeOffsetEstimator(R_B_C, min_rotations=10)
        _feed(est, -0.010, seed, keyframes=True)
        e = est.estimate()
        assert isinstance(e, TdEstimate) and abs(e.td_s + 0.010) < 1e-3
        free = TimeOffsetEstimator()  # the mount fitted from the rates
        _feed(free, 0.020, seed)
        f = free.estimate()
        assert isinstance(f, TdEstimate) and abs(f.td_s - 0.020) < 1e-3 and f.converged


def test_the_vios_long_window_settles_keyframe_rotations_a_short_one_does_not() -> None:
    """Keyframe spans (2-6 frames apart) with the noise of rotations from blurred images
    (0.3 degrees), 40 s, 10 seeds, a 4 ms offset: the VIO's window (``td_window_s``, 30 s)
    gives an RMS error under a millisecond, under 0.6 of a 6 s window's (1 / sqrt(5) expected
    from five times the spans; on realistic corridor1 the 6 s window's answers wandered from
    -1.8 to 3.8 ms)."""
    long_s = VioConfig().td_window_s
    err = {6.0: [], long_s: []}
    for seed in range(10):
        for window_s in err:
            est = TimeOffsetEstimator(R_B_C, window_s=window_s)
            _feed(est, 0.004, 40 + seed, duration_s=40.0, keyframes=True, noise_deg=0.3)
            e = est.estimate()
            err[window_s].append(np.inf if e is None else abs(e.td_s - 0.004))
    rms = {w: float(np.sqrt(np.mean(np.square(e)))) for w, e in err.items()}
    assert rms[long_s] < 1e-3, rms
    assert rms[long_s] < 0.6 * rms[6.0], rms


def _feed_turn(est: TimeOffsetEstimator, td_s: float, seed: int, *, sway_period_s: float) -> None:
    """40 s of a steady turn (0.3 rad/s of yaw) swaying 10 degrees either side, as a lap flies,
    in keyframe spans whose vision rotations have 0.1 degrees of noise and an error about the
    body's z that follows the sway's angle (as the translation's share of a rotation does:
    the sideways speed follows the heading's sway): 0.03 rad/s per radian of sway. For a sway
    of angular frequency W that error is a shift of the rate by -0.03 / W^2: 27 ms at a 6 s
    period, 1.7 ms at 1.5 s."""
    rng = np.random.default_rng(seed)
    amp, om = np.radians(10.0), 2.0 * np.pi / sway_period_s

    def attitude(t: np.ndarray) -> Rotation:
        yaw = 0.3 * t + amp * np.sin(om * t)
        return Rotation.from_euler("ZYX", np.column_stack([yaw, 0.02 * np.sin(0.7 * t), 0 * t]))

    tg = np.arange(0.0, 40.0, 0.005)
    w = (attitude(tg - _H_S / 2).inv() * attitude(tg + _H_S / 2)).as_rotvec() / _H_S
    w = w + rng.normal(0.0, 1.7e-4 * np.sqrt(200.0), w.shape) + 0.01
    tc = np.arange(0.2, 39.8, 0.05)
    R_W_B = attitude(tc)
    stamps_ns = np.rint((tc - td_s) * NS_PER_S).astype(np.int64)
    g, prev, k = 0, 0, 1
    while k < len(tc):
        while g < len(tg) and tg[g] <= tc[k] + 0.12:
            est.push_gyro(int(np.rint(tg[g] * NS_PER_S)), w[g])
            g += 1
        span_s, mid_s = tc[k] - tc[prev], 0.5 * (tc[k] + tc[prev])
        follow = Rotation.from_rotvec([0.0, 0.0, 0.03 * amp * np.sin(om * mid_s) * span_s])
        noise = Rotation.from_rotvec(rng.normal(0.0, np.radians(0.1), 3))
        R_C0_C1 = R_B_C.inv() * (R_W_B[prev].inv() * R_W_B[k]) * follow * R_B_C * noise
        est.push_rotation(int(stamps_ns[prev]), int(stamps_ns[k]), R_C0_C1)
        prev, k = k, k + int(rng.integers(2, 7))


def test_a_steady_turn_is_not_taken_for_an_offset() -> None:
    """On a lap's steady, slowly swaying turn the rate changes by 0.1-0.2 rad/s^2, too little
    to tell a 4 ms offset from vision's errors that follow the motion: every answer is marked
    not excited (measured 0.11-0.15; the answers are 17-30 ms off with sigmas of 7-11 ms). The
    same errors on a sway four times faster are excited (2.1) and shift the offset by their
    1.7 ms (1.2-2.0 measured), found within 2.5 ms."""
    for seed in range(5):
        slow = TimeOffsetEstimator(R_B_C, window_s=30.0)
        _feed_turn(slow, 0.004, seed, sway_period_s=6.0)
        e = slow.estimate()
        assert e is not None and not e.excited and e.excitation_rad_s2 < 0.3, e
        fast = TimeOffsetEstimator(R_B_C, window_s=30.0)
        _feed_turn(fast, 0.004, seed, sway_period_s=1.5)
        f = fast.estimate()
        assert f is not None and f.excited and abs(f.td_s - 0.004) < 2.5e-3, f


def test_the_sigma_holds_over_seeds() -> None:
    """Keyframe spans with 0.3 degrees of noise, 10 seeds, a 4 ms offset, the VIO's window:
    the errors over the claimed sigmas have an RMS between 0.5 and 1.5 (neither sure beyond
    the data nor uselessly loose)."""
    z = []
    for seed in range(10):
        est = TimeOffsetEstimator(R_B_C, window_s=VioConfig().td_window_s)
        _feed(est, 0.004, 40 + seed, duration_s=40.0, keyframes=True, noise_deg=0.3)
        e = est.estimate()
        assert e is not None and e.excited
        z.append((e.td_s - 0.004) / e.sigma_s)
    assert 0.5 < float(np.sqrt(np.mean(np.square(z)))) < 1.5, z


def test_no_rotation_change_or_too_little_data_gives_none() -> None:
    est = TimeOffsetEstimator(R_B_C)
    _feed(est, 0.01, 0, spin_only=True)
    assert est.estimate() is None
    short = TimeOffsetEstimator(R_B_C)
    _feed(short, 0.01, 0, duration_s=1.2)
    assert short.estimate() is None


def test_bad_input_is_refused_and_old_stamps_are_counted() -> None:
    est = TimeOffsetEstimator(R_B_C)
    with pytest.raises(VioError, match="w_B"):
        est.push_gyro(0, [0.0, np.nan, 0.0])
    with pytest.raises(VioError, match="R_C0_C1"):
        est.push_rotation(0, 50_000_000, np.full((3, 3), np.inf))
    with pytest.raises(VioError, match="not a rotation"):
        est.push_rotation(0, 50_000_000, 2.0 * np.eye(3))
    with pytest.raises(VioError, match="t1_ns"):
        est.push_rotation(50_000_000, 50_000_000, np.eye(3))
    twin = TimeOffsetEstimator(R_B_C)
    for e in (est, twin):
        _feed(e, 0.005, 1)
    est.push_gyro(1_000_000_000, [5.0, 5.0, 5.0])  # older than the buffer's newest: ignored
    est.push_rotation(1_000_000_000, 1_050_000_000, Rotation.from_rotvec([0.5, 0.0, 0.0]))
    assert est.rejected == {"gyro_out_of_order": 1, "rotation_out_of_order": 1}
    a, b = est.estimate(), twin.estimate()
    assert a is not None and a == b


@pytest.fixture(scope="module")
def room8(tmp_path_factory: pytest.TempPathFactory) -> VisualInertialDataset:
    """8 s in the room, a start in motion, EuRoC's left camera, ideal sensors."""
    return rendered(
        tmp_path_factory, "room_medium", duration_s=8.0, still_s=0.0, rig="euroc_mono", seed=4
    )


_RUNS: dict[tuple[int, int, VioConfig | None], tuple[float, VioEstimator]] = {}


def _last_td_s(
    ds: VisualInertialDataset, early_ns: int, config: VioConfig | None = None
) -> tuple[float, VioEstimator]:
    """:func:`_run_td_s`, once for each dataset, offset and configuration."""
    key = (id(ds), early_ns, config)
    if key not in _RUNS:
        _RUNS[key] = _run_td_s(ds, early_ns, config)
    return _RUNS[key]


def _run_td_s(
    ds: VisualInertialDataset, early_ns: int, config: VioConfig | None = None
) -> tuple[float, VioEstimator]:
    """The offset of the VIO's last state over ``ds``'s left camera stamped ``early_ns``
    early (the calibration not saying so), in the order of the stamps."""
    vio = VioEstimator(ds.rig, config)
    moved = (
        dataclasses.replace(s, t_ns=s.t_ns - early_ns) if isinstance(s, ImageFrame) else s
        for s in ds.stream()
        if not (isinstance(s, ImageFrame) and s.camera != "cam0")
    )
    last = None
    for s in sorted(moved, key=lambda s: s.t_ns):
        state = vio.push(s)
        last = state if state is not None else last
    assert last is not None and last.td_s is not None
    return last.td_s, vio


@pytest.mark.slow  # two more VIO runs; the default's offset is tested in CI
def test_the_online_offset_is_weighed_against_the_stated_one(room8: VisualInertialDataset) -> None:
    """Images 8 ms early, the calibration saying 0. With the stated offset said good to 0.5 ms
    (``td_prior_sigma_s``), the VIO moves less far than with the default 3 ms (the estimate's
    sigma is a few tenths of a millisecond, so the weights differ); said good to 0.1 ms, the
    estimate is less sure than the stated offset and is not used at all: its one ``td`` event
    says the offset is held at the stated one."""
    default, _ = _last_td_s(room8, 8_000_000)
    weighed, _ = _last_td_s(room8, 8_000_000, VioConfig(td_prior_sigma_s=5e-4))
    held, vio = _last_td_s(room8, 8_000_000, VioConfig(td_prior_sigma_s=1e-4))
    assert 1e-3 < weighed < default - 5e-4, (weighed, default)
    said = [e.detail for e in vio.events if e.kind == "td"]
    assert held == 0.0 and len(said) == 1 and said[0].startswith("camera-IMU offset held at 0.00")


@pytest.mark.parametrize("early_ns", [0, 8_000_000])
def test_the_vio_finds_an_unstated_offset_by_default(
    room8: VisualInertialDataset, early_ns: int
) -> None:
    """Rendered images of a start in motion, stamped ``early_ns`` before the IMU's clock
    says they were taken, with a calibration that does not say so (as the realistic datasets
    make them): the VIO's default estimates the offset within 1.5 ms (measured: 0.9 ms for 0,
    8.7 for 8), and says so in a ``td`` event."""
    td, vio = _last_td_s(room8, early_ns)
    assert abs(td - early_ns / NS_PER_S) < 1.5e-3, td
    assert any(e.kind == "td" for e in vio.events), vio.events


@pytest.mark.slow  # a render and a VIO run (test_a_steady_turn_is_not_taken_for_an_offset: the gate)
def test_the_vio_holds_an_offset_a_lap_cannot_show(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    """Rendered laps of the room (a steady turn), images 4 ms early, the calibration saying 0:
    the rate changes too slowly (0.25 rad/s^2) for the online offset, so the VIO keeps the
    stated 0 and says why in a ``td`` event. Before the gate it moved to 1.4 ms here (ideal
    sensors); on the realistic room laps to -3.5..+17.7 ms (true: 2.5-4.4)."""
    laps = rendered(tmp_path_factory, "room_laps", duration_s=8.0, still_s=0.0, seed=2)
    td, vio = _last_td_s(laps, 4_000_000)
    said = [e.detail for e in vio.events if e.kind == "td"]
    assert td == 0.0 and said, said
    assert all(d.startswith("camera-IMU offset held at 0.00 ms: not observable") for d in said)
