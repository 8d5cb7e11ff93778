"""The main job's flight: the rigid body flown by a controller on an estimator's output, fed by
sensor channels.

:func:`run_nav` composes the loop from parts, each chosen by the scenario
(:class:`~quadnav.experiments.nav_config.NavScenario`):

* the channels of :mod:`quadnav.experiments.nav_channels` (a sensor, its faults, its delay, its
  own random stream), iterated over each step;
* the estimator of :data:`ESTIMATORS` by ``estimator.kind`` (the navigation EKF levelled on the
  ground, or the truth), pushed every sample that arrives;
* the cascaded PID on the estimator's output (or on the truth with ``closed_loop: false``);
* the plan (take off, hold, square, hold, land) and a logger of typed rows.

It returns arrays (:class:`NavRunResult`); files and plots belong to ``io`` and ``eval``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.control.base import Controller, Setpoint, SetpointSource, truth_estimate
from quadnav.control.cascaded_pid import CascadedPid
from quadnav.control.thesis003 import OuterLoopController, TakeoffForward, Thesis003Gains
from quadnav.errors import ExperimentError, SimError
from quadnav.estimation.horizon import HorizonConfig, SourceFusion, SourceStats
from quadnav.estimation.nav_ekf import NavEkfConfig
from quadnav.estimation.nav_filter import (
    AligningNavFilter,
    AlignmentSigmas,
    EstimatorReport,
    ImuCounts,
    InitialSigmas,
    NavEstimator,
    NavFilterSetup,
    TruthEstimator,
    ground_alignment,
)
from quadnav.experiments.nav_channels import FlightPhase, build_channels
from quadnav.experiments.nav_config import NavScenario
from quadnav.experiments.vio_flight import (
    OdometryShortcut,
    OdometrySink,
    VioCameraSensor,
    VioRecord,
)
from quadnav.jit import njit
from quadnav.messages import Sample, StateEstimate, VehicleState
from quadnav.sim.channels import Channel
from quadnav.sim.rigid_body import RigidBodyQuadrotor
from quadnav.units import s_to_ns
from quadnav.vehicle import RigidBodyParams

__all__ = [
    "ESTIMATORS",
    "ImuCounts",
    "NavRunResult",
    "NavScenario",
    "ground_alignment",
    "heading_reference",
    "nav_estimator",
    "run_nav",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class NavRunResult:
    """Per IMU step after alignment (current horizon ``t_ns``), plus fusion records."""

    scenario: NavScenario
    seed: int
    t_ns: NDArray[np.int64]
    truth_p: FloatArray
    truth_v: FloatArray
    truth_q: FloatArray
    ref_p: FloatArray
    output_p: FloatArray
    output_v: FloatArray
    output_q: FloatArray
    t_delayed_ns: NDArray[np.int64]
    delayed_x: FloatArray  # p (3), v (3), q (4), bg (3), ba (3)
    delayed_err: FloatArray  # (N, 15) true minus estimate (attitude as a body rotation vector)
    delayed_P: FloatArray
    vision_t_ns: NDArray[np.int64]
    fusion: Mapping[str, SourceFusion]
    sources: Mapping[str, SourceStats]
    imu: ImuCounts
    t_align_ns: int
    events: list[tuple[int, str]] = field(default_factory=list)  # the filter's own log
    stream: list[Sample] | None = None  # every sample the estimator got, in arrival order
    sample_times_ns: Mapping[str, NDArray[np.int64]] = field(default_factory=dict)
    # Per logged step, whether the plan hovers there (None: the square's holds, from ref_p)
    hover: NDArray[np.bool_] | None = None
    vio: VioRecord | None = None  # what the VIO did (vio.enabled)


def _ekf_estimator(sc: NavScenario, gravity_m_s2: float, max_delay_ns: int) -> NavEstimator:
    ic, es = sc.imu, sc.estimator
    ekf = NavEkfConfig(
        gyro_sigma_rad_s=ic.gyro_sigma_rad_s * es.imu_noise_inflation,
        accel_sigma_m_s2=ic.accel_sigma_m_s2 * es.imu_noise_inflation,
        gyro_bias_rw_rad_s_sqrt_s=ic.gyro_bias_rw_rad_s_sqrt_s * es.bias_rw_inflation,
        accel_bias_rw_m_s2_sqrt_s=ic.accel_bias_rw_m_s2_sqrt_s * es.bias_rw_inflation,
        gravity_m_s2=gravity_m_s2,
        gate_probability=es.gate_probability,
        datum_lla=sc.gps.datum_lla,
        mag_declination_rad=sc.mag.declination_rad,
        vision_frame=es.vision_frame,
        reset_after_s=es.reset_after_s,
        odometry_fuse=tuple(sc.vio.fuse),
        odometry_pos_noise_m=sc.vio.pos_noise_m,
        odometry_vel_noise_m_s=sc.vio.vel_noise_m_s,
        odometry_yaw_noise_rad=sc.vio.yaw_noise_rad,
        odometry_gate_sigma=sc.vio.gate_sigma,
        # without a VIO no odometry is fused: its frame's drift is not estimated
        odometry_mode=sc.vio.odometry_mode if sc.vio.enabled else "absolute",
        # loop closure's output (and the SLAM's) jumps only to correct itself (after a reset of
        # the VIO it goes on where it was): the filter follows it, as PX4's EKF2 does
        follow_resets=("vio",) if sc.vio.enabled and sc.vio.corrects_in_place else (),
        odometry_drift_m_sqrt_s=sc.vio.frame_drift_m_sqrt_s,
        odometry_drift_yaw_rad_sqrt_s=sc.vio.frame_drift_yaw_rad_sqrt_s,
        odometry_scale_sigma=sc.vio.frame_scale_sigma,
        odometry_scale_rw_sqrt_s=sc.vio.frame_scale_rw_sqrt_s,
        odometry_drift_from_covariance=sc.vio.frame_drift_from_covariance,
    )
    horizon = HorizonConfig(
        imu_period_ns=s_to_ns(1.0 / ic.rate_hz),
        max_delay_ns=max_delay_ns,
        tau_vel_s=es.tau_vel_s,
        tau_pos_s=es.tau_pos_s,
    )
    bg0 = es.init_gyro_bias_sigma_rad_s or max(ic.gyro_bias0_sigma_rad_s, 1e-4)
    ba0 = es.init_accel_bias_sigma_m_s2 or max(ic.accel_bias0_sigma_m_s2, 1e-3)
    sigmas = InitialSigmas(
        tilt_rad=es.init_tilt_sigma_rad,
        vel_m_s=es.init_vel_sigma_m_s,
        gyro_bias_rad_s=bg0,
        accel_bias_m_s2=ba0,
    )
    alignment = AlignmentSigmas(
        pose_factor=es.init_source_sigma_factor,
        gps_factor=es.init_gps_sigma_factor,
        yaw_from_mag_rad=es.init_yaw_sigma_mag_rad,
        yaw_unknown_rad=es.init_yaw_sigma_unknown_rad,
        pos_unknown_m=es.init_pos_sigma_unknown_m,
        start_pose=_start_pose(es.start_pose),
        start_pos_sigma_m=es.start_pos_sigma_m,
        start_yaw_sigma_rad=math.radians(es.start_yaw_sigma_deg),
    )
    return AligningNavFilter(
        NavFilterSetup(ekf=ekf, horizon=horizon, sigmas=sigmas),
        align_ns=s_to_ns(es.align_s),
        alignment=alignment,
        heading_from_pose=es.vision_frame != "rotate",
        gyro_bias_at_rest=es.gyro_bias_at_rest,
    )


def _start_pose(
    pose: tuple[float, float, float, float] | None,
) -> tuple[float, float, float, float] | None:
    """``estimator.start_pose`` with its heading in radians."""
    return None if pose is None else (pose[0], pose[1], pose[2], math.radians(pose[3]))


def _truth_estimator(sc: NavScenario, gravity_m_s2: float, max_delay_ns: int) -> NavEstimator:
    del sc, gravity_m_s2, max_delay_ns
    return TruthEstimator()


#: The estimators ``estimator.kind`` chooses from: (scenario, gravity, largest channel delay).
ESTIMATORS: dict[str, Callable[[NavScenario, float, int], NavEstimator]] = {
    "ekf": _ekf_estimator,
    "truth": _truth_estimator,
}


def nav_estimator(sc: NavScenario, gravity_m_s2: float, channels: list[Channel]) -> NavEstimator:
    """The scenario's estimator, its horizon as long as its slowest channel needs."""
    max_delay = max((ch.delay_ns for ch in channels), default=0)
    return ESTIMATORS[sc.estimator.kind](sc, gravity_m_s2, max_delay)


def heading_reference(
    v: FloatArray, dt_s: float, mode: str, max_rate_rad_s: float, min_speed_m_s: float = 0.2
) -> FloatArray:
    """Yaw setpoints per step: 0, or the direction of horizontal travel (held while slow),
    turned towards at no more than ``max_rate_rad_s``."""
    n = len(v)
    out = np.zeros(n)
    if mode == "fixed":
        return out
    target, yaw, step = 0.0, 0.0, max_rate_rad_s * dt_s
    for k in range(n):
        if math.hypot(v[k, 0], v[k, 1]) > min_speed_m_s:
            target = math.atan2(v[k, 1], v[k, 0])
        yaw += min(max(math.remainder(target - yaw, 2 * math.pi), -step), step)
        out[k] = yaw
    return out


class _Plan:
    """The plan's references per step and the flight phase: motors off on the ground until the
    plan climbs, and again once it has come down and the vehicle sits low (touch-down)."""

    def __init__(self, sc: NavScenario) -> None:
        dt = sc.sim_dt_s
        self.n_steps = round(sc.flight_s / dt)
        self.align_ns = s_to_ns(sc.estimator.align_s)
        ref = sc.waypoints().reference(np.arange(self.n_steps + 1) * dt - sc.estimator.align_s)
        self.p, self.v, self.a = ref.p, ref.v, ref.a
        self.yaw = heading_reference(ref.v, dt, sc.plan.yaw, math.radians(sc.plan.yaw_rate_deg_s))
        self.landed = False
        self.dt, self._down_steps = dt, 0

    def on_ground(self, i: int, t_ns: int) -> bool:
        return t_ns < self.align_ns or self.landed or self._down(i, first_half=True)

    def _down(self, i: int, *, first_half: bool) -> bool:
        half = self.n_steps // 2
        return bool(self.p[i][2] <= 0.0) and (i < half if first_half else i > half)

    def setpoint(self, i: int) -> Setpoint:
        return Setpoint(p=self.p[i], v=self.v[i], a=self.a[i], yaw_rad=float(self.yaw[i]))

    def touch_down(self, i: int, z_m: float, vz_m_s: float) -> bool:
        """The plan has come down and the vehicle sits low, or (a height only a GNSS measures
        can stay 0.1-0.5 m off) the plan has been down a second and the estimate sinks no more
        (PX4's land detector: commanded down, no vertical motion): cut the motors from now on.
        Left on, the controller would push the vehicle into the ground and tilt it there."""
        down = self._down(i, first_half=False)
        self._down_steps = self._down_steps + 1 if down else 0
        still = self._down_steps * self.dt >= 1.0 and abs(vz_m_s) < 0.1
        self.landed = self.landed or (down and (z_m < 0.05 or still))
        return self.landed

    def ref_p(self, i: int) -> FloatArray:
        return np.asarray(self.p[i], dtype=np.float64)

    def hovering(self, t_ns: int) -> bool | None:
        del t_ns  # (the square's holds are found from its reference)
        return None


class FlightPlan(Protocol):
    """What the loop asks its plan each step."""

    n_steps: int

    def on_ground(self, i: int, t_ns: int) -> bool: ...

    def setpoint(self, i: int) -> Setpoint: ...

    def touch_down(self, i: int, z_m: float, vz_m_s: float) -> bool: ...

    def ref_p(self, i: int) -> FloatArray: ...

    def hovering(self, t_ns: int) -> bool | None: ...


class _Recorded:
    """A setpoint source whose last setpoint can be read (the hover point it holds)."""

    def __init__(self, inner: SetpointSource) -> None:
        self.inner = inner
        self.last: Setpoint | None = None

    def __call__(self, t_ns: int, est: StateEstimate, ref: Setpoint) -> Setpoint:
        self.last = self.inner(t_ns, est, ref)
        return self.last


class _TakeoffPlan:
    """Thesis 003's section 6.3: on the ground for ``plan.takeoff_s`` after alignment (the VIO
    starts at rest), then :class:`~quadnav.control.thesis003.TakeoffForward` climbs to
    ``height_m`` and goes ``forward_m`` ahead, then holds where it stopped: a hover, counted
    from a second after it began. No landing."""

    def __init__(self, sc: NavScenario, outer: _Recorded, takeoff: TakeoffForward) -> None:
        self.n_steps = round(sc.flight_s / sc.sim_dt_s)
        self.takeoff_ns = s_to_ns(sc.estimator.align_s + sc.plan.takeoff_s)
        self.target = np.array([sc.plan.forward_m, 0.0, sc.plan.height_m])
        self._setpoint = Setpoint(p=self.target)  # (the same every step)
        self.outer, self.takeoff = outer, takeoff
        self._done_ns: int | None = None

    def on_ground(self, i: int, t_ns: int) -> bool:
        return t_ns < self.takeoff_ns

    def setpoint(self, i: int) -> Setpoint:
        return self._setpoint

    def touch_down(self, i: int, z_m: float, vz_m_s: float) -> bool:
        return False

    def ref_p(self, i: int) -> FloatArray:
        last: Setpoint | None = self.outer.last
        return (
            last.p if self.takeoff.phase == "done" and last and last.p is not None else self.target
        )

    def hovering(self, t_ns: int) -> bool | None:
        if self.takeoff.phase != "done":
            return False
        self._done_ns = t_ns if self._done_ns is None else self._done_ns
        return t_ns - self._done_ns >= 1_000_000_000


def flight_plan(sc: NavScenario, params: RigidBodyParams) -> tuple[Controller, FlightPlan]:
    """The controller and plan of ``plan.kind``: the cascaded PID on the square's trajectory,
    or thesis 003's take-off-and-forward velocity commands (10 Hz) over its velocity mode."""
    pid = CascadedPid(params, dt_s=sc.sim_dt_s)
    if sc.plan.kind == "square":
        return pid, _Plan(sc)
    gains = Thesis003Gains()
    takeoff = TakeoffForward(gains=gains)
    outer = _Recorded(takeoff)
    return OuterLoopController(outer, pid, rate_hz=gains.rate_hz), _TakeoffPlan(sc, outer, takeoff)


class _NavLog:
    """Rows per logged IMU step, in arrays as they come (blocks of ``_BLOCK`` rows): the
    truth, the plan's position, the output, the delayed horizon (its state and covariance,
    written by the estimator itself) and the IMU's true biases. The delayed horizon is scored
    against the truth logged at its time, all rows at once when the flight is over."""

    def __init__(self, *, record_stream: bool) -> None:
        self.t: list[int] = []
        self.t_delayed: list[int] = []
        self.truth_row: list[int] = []  # the row whose truth is at the delayed time (-1: none)
        self.hover: list[bool | None] = []
        self._row_at: dict[int, int] = {}
        self._rows: list[FloatArray] = []  # blocks of (_BLOCK, _WIDTH)
        self._P: list[FloatArray] = []  # blocks of (_BLOCK, 15, 15)
        self.stream: list[Sample] | None = [] if record_stream else None

    def record(
        self,
        truth: VehicleState,
        true_bias: tuple[FloatArray, FloatArray] | None,
        ref_p: FloatArray,
        out: StateEstimate,
        est: NavEstimator,
        hover: bool | None = None,
    ) -> None:
        """One row; the delayed horizon is read from ``est`` (:meth:`NavEstimator.delayed_row`)."""
        k = len(self.t) % _BLOCK
        if k == 0:
            self._rows.append(np.empty((_BLOCK, _WIDTH)))
            self._P.append(np.empty((_BLOCK, 15, 15)))
        row = self._rows[-1][k]
        bg, ba = _NO_BIAS if true_bias is None else true_bias
        _log_row(row, truth.p_W_B, truth.v_W_B, truth.q_W_B_xyzw, ref_p, out.p_W_B, out.v_W_B,
                 out.q_W_B_xyzw, bg, ba)  # fmt: skip
        t_dl = est.delayed_row(row[_DELAYED], self._P[-1][k])
        self._row_at[truth.t_ns] = len(self.t)
        self.hover.append(hover)
        self.t.append(truth.t_ns)
        self.t_delayed.append(t_dl)
        self.truth_row.append(self._row_at.get(t_dl, -1))

    def arrays(self) -> dict[str, FloatArray]:
        n = len(self.t)
        rows = _joined(self._rows, n)
        col = {name: rows[:, a:b] for name, (a, b) in _COLUMNS.items()}
        truth = {k: np.ascontiguousarray(col[k]) for k in ("truth_p", "truth_v", "truth_q")}
        dl_x = np.ascontiguousarray(col["delayed_x"])
        return {
            **truth,
            "ref_p": np.ascontiguousarray(col["ref_p"]),
            "output_p": np.ascontiguousarray(col["output_p"]),
            "output_v": np.ascontiguousarray(col["output_v"]),
            "output_q": np.ascontiguousarray(col["output_q"]),
            "delayed_x": dl_x,
            "delayed_err": self._delayed_err(truth, dl_x, col["true_bias"]),
            "delayed_P": _joined(self._P, n),
        }

    def _delayed_err(
        self, truth: dict[str, FloatArray], dl_x: FloatArray, true_bias: FloatArray
    ) -> FloatArray:
        """Per row, the truth at the delayed time less the delayed estimate: attitude (the
        body-frame rotation vector taking the estimate onto the truth), velocity, position,
        gyro and accelerometer biases (15); NaN where no truth was logged at that time."""
        err = np.full((len(self.t), 15), np.nan)
        rows = np.flatnonzero(np.array(self.truth_row, dtype=np.int64) >= 0)
        if not len(rows):
            return err
        k = np.array(self.truth_row, dtype=np.int64)[rows]
        dl = dl_x[rows]
        turn = Rotation.from_quat(dl[:, 6:10]).inv() * Rotation.from_quat(truth["truth_q"][k])
        err[rows, 0:3] = turn.as_rotvec()
        err[rows, 3:6] = truth["truth_v"][k] - dl[:, 3:6]
        err[rows, 6:9] = truth["truth_p"][k] - dl[:, 0:3]
        err[rows, 9:15] = true_bias[k] - dl[:, 10:16]
        return err


# A log row's columns: the truth's position, velocity and quaternion, the plan's position, the
# output's position, velocity and quaternion, the delayed horizon's state (p, v, q, b_g, b_a:
# NavEstimator.delayed_row) and the IMU's true biases
_COLUMNS = {
    name: (a, a + w)
    for name, w, a in zip(
        ("truth_p", "truth_v", "truth_q", "ref_p", "output_p", "output_v", "output_q",
         "delayed_x", "true_bias"),
        (3, 3, 4, 3, 3, 3, 4, 16, 6),
        (0, 3, 6, 10, 13, 16, 19, 23, 39),
        strict=True,
    )
}  # fmt: skip
_WIDTH = 45
_DELAYED = slice(*_COLUMNS["delayed_x"])
_BLOCK = 16384  # (a minute at 250 Hz in one block: np.empty's pages are touched as rows come)


def _joined(blocks: list[FloatArray], n: int) -> FloatArray:
    """The first ``n`` rows of the blocks: a view of the first when it holds them all (no
    copy of tens of megabytes, whose fresh pages cost as much again), else one array."""
    if len(blocks) == 1:
        return blocks[0][:n]
    return np.concatenate(blocks)[:n]


_NO_BIAS = (np.full(3, np.nan), np.full(3, np.nan))


@njit
def _log_row(
    row: FloatArray, tp: FloatArray, tv: FloatArray, tq: FloatArray, ref_p: FloatArray,
    op: FloatArray, ov: FloatArray, oq: FloatArray, bg: FloatArray, ba: FloatArray,
) -> None:  # fmt: skip
    """``row``'s columns (:data:`_COLUMNS`) but the delayed horizon's: the truth's position,
    velocity and quaternion, the plan's position, the output's, the true biases."""
    for k in range(3):
        row[k], row[3 + k], row[10 + k], row[13 + k] = tp[k], tv[k], ref_p[k], op[k]
        row[16 + k], row[39 + k], row[42 + k] = ov[k], bg[k], ba[k]
    for k in range(4):
        row[6 + k], row[19 + k] = tq[k], oq[k]


def _vio_record(channels: list[Channel]) -> VioRecord | None:
    for ch in channels:
        if isinstance(ch.sensor, VioCameraSensor | OdometryShortcut):
            return ch.sensor.record()
    return None


def _result(
    sc: NavScenario, seed: int, log: _NavLog, channels: list[Channel], report: EstimatorReport
) -> NavRunResult:
    by_name = {ch.name: ch for ch in channels}
    imu = by_name["imu"]
    hover = None if any(h is None for h in log.hover) else np.array(log.hover, dtype=bool)
    times = {ch.name: np.array(ch.sampled_t_ns, dtype=np.int64) for ch in channels}
    return NavRunResult(
        scenario=sc,
        seed=seed,
        t_ns=np.array(log.t, dtype=np.int64),
        t_delayed_ns=np.array(log.t_delayed, dtype=np.int64),
        vision_t_ns=times.get("vision", np.zeros(0, dtype=np.int64)),
        fusion=report.fusion,
        sources=report.sources,
        imu=ImuCounts(
            received=report.imu_received,
            rejected_out_of_order=report.imu_rejected_out_of_order,
            rejected_invalid=imu.rejected_invalid + report.rejected_invalid.get("ImuSample", 0),
        ),
        t_align_ns=s_to_ns(sc.estimator.align_s),
        events=list(report.events),
        stream=log.stream,
        sample_times_ns=times,
        hover=hover,
        vio=_vio_record(channels),
        **log.arrays(),
    )


def _true_biases(imu: Channel) -> tuple[FloatArray, FloatArray] | None:
    """The gyro and accelerometer biases the IMU's next sample carries (None: it has none)."""
    sensor = imu.sensor
    bg, ba = getattr(sensor, "bias_g", None), getattr(sensor, "bias_a", None)
    return None if bg is None or ba is None else (bg, ba)


def run_nav(
    sc: NavScenario,
    seed: int,
    *,
    record_stream: bool = False,
    odometry_sink: OdometrySink | None = None,
    progress: Callable[[float], None] | None = None,
) -> NavRunResult:
    """Align on the ground, fly the plan, and log truth, estimates and fusions. The VIO's
    odometry also goes to ``odometry_sink``; ``progress`` gets the fraction flown (each 1 %)."""
    params = RigidBodyParams()
    sim = RigidBodyQuadrotor(params, dt_s=sc.sim_dt_s)
    phase = FlightPhase()
    channels = build_channels(
        sc, seed, phase, gravity_m_s2=params.gravity_m_s2, odometry_sink=odometry_sink
    )
    imu = next(ch for ch in channels if ch.name == "imu")
    est = nav_estimator(sc, params.gravity_m_s2, channels)
    (ctrl, plan), log = flight_plan(sc, params), _NavLog(record_stream=record_stream)
    every = max(1, plan.n_steps // 100)
    out: StateEstimate | None = None
    try:
        for i in range(plan.n_steps):
            truth = sim.state()
            t = truth.t_ns
            phase.motors_off = plan.on_ground(i, t)
            was_ready, pushed = est.ready, False
            for ch in channels:  # (the times first: most steps, most channels do nothing)
                if t >= ch.idle_until_ns:
                    ch.step(truth, t)
            for ch in channels:
                if t < ch.next_arrival_ns:
                    continue
                for smp in ch.arrived(t):
                    est.push(smp)
                    pushed = True
                    if was_ready and log.stream is not None:
                        log.stream.append(smp)
            if pushed or out is None:  # (an estimate changes only with what it is pushed)
                out = est.output() if est.ready else None
            if was_ready and out is not None and imu.sampled_t_ns and imu.sampled_t_ns[-1] == t:
                hover = plan.hovering(t)
                log.record(truth, _true_biases(imu), plan.ref_p(i), out, est, hover)
            if phase.motors_off:
                cmd = np.zeros(4)
            else:
                fly_on = out if sc.closed_loop and out is not None else truth_estimate(truth)
                cmd = ctrl(t, fly_on, plan.setpoint(i)).rotors()
                if plan.touch_down(i, float(fly_on.p_W_B[2]), float(fly_on.v_W_B[2])):
                    cmd = np.zeros(4)
            sim.step(cmd)
            if progress is not None and i % every == 0:
                progress(i / plan.n_steps)
    except SimError as exc:
        raise ExperimentError(f"scenario {sc.name!r} seed {seed}: {exc}") from None
    if not est.ready or not log.t:
        raise ExperimentError(
            f"scenario {sc.name!r}: the flight ended before the filter was aligned"
        )
    return _result(sc, seed, log, channels, est.report())
