"""The drifting-odometry model (the VIO's shortcut, issue 25): its yaw drift turns only the
motion after it, its scale error scales the motion, its resets restart it with the counter
up, and its spread of drift is the one asked for, over seeds."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import ConfigError
from quadnav.experiments.vio_flight import OdometryShortcut
from quadnav.messages import OdometrySample, VehicleState
from quadnav.units import s_to_ns

RATE_NS = 50_000_000  # 20 Hz


def _truth(t_ns: int, speed: float = 2.0) -> VehicleState:
    """A vehicle flying east at ``speed`` m/s, 3 m up, facing east."""
    t = t_ns * 1e-9
    return VehicleState(
        t_ns=t_ns, p_W_B=np.array([speed * t, 0.0, 3.0]), v_W_B=np.array([speed, 0.0, 0.0]),
        a_W_B=np.zeros(3), q_W_B_xyzw=np.array([0.0, 0.0, 0.0, 1.0]), w_B=np.zeros(3),
    )  # fmt: skip


def _run(odo: OdometryShortcut, seconds: float, seed: int = 0) -> list[OdometrySample]:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(1, int(seconds * 1e9 / RATE_NS) + 1):
        t = k * RATE_NS
        s = odo.sample(_truth(t), t, rng)
        if s is not None:
            out.append(s)
    return out


def _quiet(**kw: object) -> OdometryShortcut:
    return OdometryShortcut(
        period_ns=RATE_NS, sigma_m=1e-6, sigma_vel_m_s=1e-6, sigma_att_rad=1e-7, **kw
    )  # type: ignore[arg-type]


def test_without_drift_it_is_the_truth() -> None:
    out = _run(_quiet(), 5.0)
    assert len(out) == 100
    for s in out:
        assert np.allclose(s.p_W_B, _truth(s.t_ns).p_W_B, atol=1e-4)
        assert s.reset_counter == 0


def test_a_scale_error_scales_the_motion_not_the_start() -> None:
    out = _run(_quiet(scale_error=0.1), 10.0)
    start = _truth(out[0].t_ns).p_W_B
    moved = out[-1].p_W_B - start
    assert moved[0] == pytest.approx(1.1 * (20.0 - 0.05 * 2.0), rel=1e-4)
    assert out[-1].v_W_B[0] == pytest.approx(2.2, rel=1e-4)


def test_a_reset_restarts_at_zero_with_a_new_yaw_and_the_counter_up() -> None:
    out = _run(_quiet(resets_ns=[s_to_ns(4.0), s_to_ns(7.0)]), 10.0, seed=3)
    counters = [s.reset_counter for s in out]
    assert counters[0] == 0 and counters[-1] == 2 and sorted(counters) == counters
    first_after = next(s for s in out if s.reset_counter == 1)
    assert first_after.t_ns == s_to_ns(4.0) and np.allclose(first_after.p_W_B, 0.0, atol=1e-4)
    # after the reset, moving east at 2 m/s shows as 2 m/s along the new frame's heading
    yaw = Rotation.from_quat(first_after.q_W_B_xyzw).as_euler("ZYX")[0]
    v = first_after.v_W_B
    assert math.hypot(v[0], v[1]) == pytest.approx(2.0, rel=1e-4)
    assert math.atan2(v[1], v[0]) == pytest.approx(yaw, abs=1e-5)
    later = out[out.index(first_after) + 20]  # one second later: 2 m along that heading
    assert np.allclose(later.p_W_B, [2 * math.cos(yaw), 2 * math.sin(yaw), 0.0], atol=1e-3)


def test_the_drift_spreads_as_asked_over_seeds() -> None:
    """Position drift 0.05 m/sqrt(s) per axis and yaw drift 0.01 rad/sqrt(s): after 10 s the
    spread over 100 seeds is 0.158 m up (the origin's walk; across the track the yaw's turn of
    the 20 m flown adds to it) and 0.0316 rad of yaw, within sampling error (7 % a sigma)."""
    yaw_end, err_z = [], []
    for seed in range(100):
        odo = _quiet(drift_m_sqrt_s=0.05, drift_yaw_rad_sqrt_s=0.01)
        s = _run(odo, 10.0, seed)[-1]
        yaw_end.append(Rotation.from_quat(s.q_W_B_xyzw).as_euler("ZYX")[0])
        err_z.append(s.p_W_B[2] - 3.0)
    assert np.std(yaw_end) == pytest.approx(0.01 * math.sqrt(10.0), rel=0.2)
    assert np.std(err_z) == pytest.approx(0.05 * math.sqrt(10.0), rel=0.2)


def test_a_yaw_drift_turns_only_the_motion_after_it() -> None:
    """Hovering (no motion) under a yaw drift, the position stays: a rotation of the whole
    trajectory about the start would have moved it."""
    rng = np.random.default_rng(1)
    odo = _quiet(drift_yaw_rad_sqrt_s=0.2)
    still = VehicleState(
        t_ns=0, p_W_B=np.array([30.0, -20.0, 3.0]), v_W_B=np.zeros(3), a_W_B=np.zeros(3),
        q_W_B_xyzw=np.array([0.0, 0.0, 0.0, 1.0]), w_B=np.zeros(3),
    )  # fmt: skip
    out = [odo.sample(still, k * RATE_NS, rng) for k in range(1, 201)]
    assert np.ptp([s.p_W_B for s in out if s is not None], axis=0).max() < 1e-4
    yaws = [Rotation.from_quat(s.q_W_B_xyzw).as_euler("ZYX")[0] for s in out if s is not None]
    assert np.ptp(yaws) > 0.3


def test_an_absurd_scale_error_is_refused() -> None:
    with pytest.raises(ConfigError, match="scale error"):
        _quiet(scale_error=0.9)


def _record_across_a_reset(gap_s: float) -> tuple[object, float]:
    """An exact odometry along x at 3 m/s for 10 s whose world restarts at 5 s (its origin
    where it then is, turned 90 degrees), and gives nothing for ``gap_s`` before that."""
    from quadnav.experiments.vio_flight import VioRecord

    t = np.arange(0.0, 10.0, 0.05)
    keep = (t < 5.0 - gap_s) | (t >= 5.0)
    t = t[keep]
    truth = np.column_stack([3.0 * t, np.zeros_like(t), np.full_like(t, 2.0)])
    second = t >= 5.0
    turn = Rotation.from_euler("z", 90, degrees=True)
    p = truth.copy()
    p[second] = turn.apply(truth[second] - truth[second][0])
    q = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))
    q[second] = turn.as_quat()
    rec = VioRecord(
        t_ns=np.round(t * 1000).astype(np.int64) * 1_000_000, p_W_B=p, q_W_B_xyzw=q,
        reset_counter=second.astype(np.int64), truth_p_W_B=truth,
        truth_q_W_B_xyzw=np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1)),
    )  # fmt: skip
    return rec, float(np.mean(second))


def test_the_odometry_alone_carries_on_across_a_reset_from_where_it_last_was() -> None:
    """Judged alone, an odometry that resets goes on from its last pose: an exact one with no
    gap stays on the truth; one silent for 1 s at 3 m/s is 3 m off from then on (before,
    only the last world was judged, and a VIO that failed halfway looked good)."""
    from quadnav.experiments.nav_study import _odometry_alone

    rec, _ = _record_across_a_reset(0.0)
    assert _odometry_alone(rec) < 0.2  # (one 5 cm step of motion between the two worlds)
    rec, share = _record_across_a_reset(1.0)
    expected = math.sqrt(share) * 3.0 * 1.05  # 3 m, plus the step of the frame period
    assert _odometry_alone(rec) == pytest.approx(expected, rel=0.05)
