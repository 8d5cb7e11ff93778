"""The delayed-horizon core: IMU ring buffer, per-sensor observation buffers, output predictor.

This is the estimator structure of PX4 EKF2 that thesis 000 (chapter 2) explains, written
once and shared by every filter in quadnav:

* The filter (any :class:`DelayedFilter`) runs ``max_delay`` behind the newest IMU sample,
  at the *delayed horizon*. The IMU ring buffer is as long as the largest configured sensor
  delay needs (PX4's rule, ``delay / imu_period + 1``, rounded up so a delay between two
  IMU ticks still fits).
* Observations wait in a buffer per source, ordered by their time of validity, and are fused
  when the delayed horizon reaches that time, whatever order they arrived in. One that
  arrives after the horizon has passed it is rejected and counted.
* The *output predictor* integrates every new IMU sample at the current horizon and is pulled
  towards the filter: a proportional-integral correction of velocity and position applied to
  the whole output buffer with gains ``dt / tau``, and an attitude correction fed through the
  delta angle with gain ``0.5 * dt / delay`` (PX4 ``applyCorrectionToOutputBuffer`` and
  ``calculateOutputStates``). One addition, on by default and measured in the planar
  experiment: a velocity correction also shifts each buffered position by the correction
  times that entry's age, so the buffer stays kinematically consistent.

What is model-specific (the strapdown integration and the attitude error) comes in through a
:class:`Kinematics`; the filter's own equations through a :class:`DelayedFilter`.
"""

from __future__ import annotations

import dataclasses
import heapq
import math
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import EstimationError, SampleError
from quadnav.jit import njit
from quadnav.messages import (
    ImuSample,
    Sample,
    StateEstimate,
    check_t_ns,
)

__all__ = [
    "DelayedFilter",
    "DelayedHorizonEstimator",
    "Estimator",
    "FusionRecord",
    "FusionResult",
    "HorizonConfig",
    "Kinematics",
    "NavState",
    "SourceCounters",
    "SourceFusion",
    "SourceStats",
    "correct_ring",
    "fusion_arrays",
    "imu_buffer_length",
    "integrate_ring",
    "require_positive",
]

FloatArray = NDArray[np.float64]


def require_positive(obj: object, names: tuple[str, ...]) -> None:
    """Each named field of a config must be a finite number > 0 (else an EstimationError
    naming ``Type.field``)."""
    for name in names:
        v = getattr(obj, name)
        if not (math.isfinite(v) and v > 0):
            raise EstimationError(f"{type(obj).__name__}.{name} must be finite and > 0, got {v}")


def imu_buffer_length(*, max_delay_ns: int, imu_period_ns: int) -> int:
    """IMU buffer length for a largest sensor delay (PX4: ``delay / period + 1``, rounded up)."""
    if imu_period_ns <= 0:
        raise EstimationError(f"the IMU period must be > 0 ns, got {imu_period_ns}")
    if max_delay_ns < 0:
        raise EstimationError(f"the largest sensor delay must be >= 0 ns, got {max_delay_ns}")
    return -(-max_delay_ns // imu_period_ns) + 1


@dataclass(slots=True)
class NavState:
    """Position, velocity and attitude at one time (model-specific array shapes)."""

    t_ns: int
    pos: FloatArray
    vel: FloatArray
    att: FloatArray

    def copy(self) -> NavState:
        return NavState(self.t_ns, self.pos.copy(), self.vel.copy(), self.att.copy())


def body_rate(gyro: FloatArray | None, bias_g: FloatArray) -> FloatArray | None:
    """A gyro reading less the gyro bias (None without a reading, or where the shapes differ:
    a filter whose bias is not the reading's)."""
    if gyro is None or gyro.shape != bias_g.shape:
        return None
    return gyro - bias_g


class Kinematics(Protocol):
    """Strapdown integration shared by a filter's mean, the output predictor and diagnostics.

    Arrays may carry leading batch axes: ``pos`` (..., P), ``vel`` (..., P), ``att`` (..., A),
    ``gyro``/``accel`` (..., 3) in the body frame, ``dt_s`` broadcastable to the batch,
    ``dtheta_corr`` a delta-angle correction (..., 3) added to ``gyro * dt``.
    """

    def integrate(
        self,
        pos: FloatArray,
        vel: FloatArray,
        att: FloatArray,
        gyro: FloatArray,
        accel: FloatArray,
        dt_s: FloatArray | float,
        dtheta_corr: FloatArray | None = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray]: ...

    def integrate_ring(
        self, ring: tuple[FloatArray, FloatArray, FloatArray], src: int, dst: int,
        imu: ImuSample, biases: tuple[FloatArray, FloatArray], dt_s: float,
        dtheta_corr: FloatArray,
    ) -> None:  # fmt: skip
        """The output predictor's step: row ``src`` of the ring's ``(pos, vel, att)`` integrated
        with the IMU sample less the gyro and accelerometer ``biases`` into row ``dst`` (as
        :meth:`integrate` of one state; :func:`integrate_ring` is that)."""
        ...

    def attitude_error(self, att_target: FloatArray, att: FloatArray) -> FloatArray:
        """The delta angle (3,) that rotates ``att`` onto ``att_target``."""
        ...

    def correct_ring(
        self, ring: tuple[FloatArray, FloatArray, FloatArray], ring_t: NDArray[np.int64],
        oldest: int, nav: NavState, integrals: tuple[FloatArray, FloatArray],
        gains: tuple[float, float, float], propagate: bool,
    ) -> FloatArray:  # fmt: skip
        """The output predictor's correction towards the delayed horizon's ``nav`` (as
        :func:`correct_ring`, which it is): the ring's positions and velocities in place, and
        the attitude's delta-angle correction (3,) returned."""
        ...

    def to_estimate(
        self,
        nav: NavState,
        x: FloatArray,
        names: tuple[str, ...],
        P: FloatArray | None,
        w_B: FloatArray | None = None,
    ) -> StateEstimate:
        """Package a navigation state in the common 3-D form (``w_B``: the body rate)."""
        ...

    def output_estimate(
        self, nav: NavState, gyro: FloatArray | None, bias_g: FloatArray
    ) -> StateEstimate:
        """:meth:`to_estimate` of the output predictor's state: ``x`` its
        ``concatenate([pos, vel, att])`` (:attr:`output_names`), no covariance; the body rate
        ``gyro - bias_g`` (None without a gyro reading, or where the shapes differ)."""
        ...

    @property
    def output_names(self) -> tuple[str, ...]:
        """Names of the output predictor's state ``concatenate([pos, vel, att])``."""
        ...


def integrate_ring(
    kin: Kinematics, ring: tuple[FloatArray, FloatArray, FloatArray], src: int, dst: int,
    imu: ImuSample, biases: tuple[FloatArray, FloatArray], dt_s: float, dtheta_corr: FloatArray,
) -> None:  # fmt: skip
    """:meth:`Kinematics.integrate_ring` through :meth:`Kinematics.integrate` (for kinematics
    with no compiled step of their own)."""
    pos, vel, att = ring
    out = kin.integrate(
        pos[src], vel[src], att[src], imu.gyro_rad_s - biases[0], imu.accel_m_s2 - biases[1],
        dt_s, dtheta_corr,
    )  # fmt: skip
    for arr, row in zip(ring, out, strict=True):
        arr[dst] = row


def correct_ring(
    kin: Kinematics, ring: tuple[FloatArray, FloatArray, FloatArray], ring_t: NDArray[np.int64],
    oldest: int, nav: NavState, integrals: tuple[FloatArray, FloatArray],
    gains: tuple[float, float, float], propagate: bool,
) -> FloatArray:  # fmt: skip
    """:meth:`Kinematics.correct_ring` through :meth:`Kinematics.attitude_error`: the error of
    the ring's ``oldest`` attitude times the attitude gain (``gains``: attitude, position,
    velocity) is returned; :func:`_pi_correct` moves the ring's positions and velocities with
    the position and velocity ``integrals``."""
    pos, vel, att = ring
    dtheta = kin.attitude_error(nav.att, att[oldest]) * gains[0]
    _pi_correct(ring_t, pos, vel, oldest, nav.pos, nav.vel, integrals[0], integrals[1],
                gains[1], gains[2], propagate)  # fmt: skip
    return dtheta


class Estimator(Protocol):
    """What every quadnav estimator offers (ARCHITECTURE.md, Interfaces)."""

    def push(self, sample: Sample) -> None:
        """Any sample, in arrival order; ``sample.t_ns`` may lie in the past."""
        ...

    def output(self) -> StateEstimate:
        """The current time horizon (output predictor)."""
        ...

    def delayed(self) -> StateEstimate:
        """The fusion horizon, with covariance."""
        ...


@dataclass(frozen=True, slots=True, kw_only=True)
class FusionResult:
    """What a filter did with one observation."""

    accepted: bool
    innovation: FloatArray
    nis: float
    test_ratio: float


@dataclass(frozen=True, slots=True, kw_only=True)
class FusionRecord:
    """A log line for one observation that reached the fusion horizon."""

    t_obs_ns: int
    t_fused_ns: int
    source: str
    result: FusionResult


@dataclass(frozen=True, slots=True, kw_only=True)
class SourceFusion:
    """One source's fusion records as arrays (one row per observation fused or gated).

    ``innovation`` is (N, width) with the widest observation's width; a narrower one (a pose
    without yaw, say) is padded with NaN.
    """

    t_obs_ns: NDArray[np.int64]
    nis: FloatArray
    test_ratio: FloatArray
    accepted: NDArray[np.bool_]
    dof: NDArray[np.int64]
    innovation: FloatArray

    def __len__(self) -> int:
        return len(self.t_obs_ns)


def fusion_arrays(log: Iterable[FusionRecord]) -> dict[str, SourceFusion]:
    """A fusion log as arrays, per source (the one conversion every run uses)."""
    by_source: dict[str, list[FusionRecord]] = {}
    for r in log:
        by_source.setdefault(r.source, []).append(r)
    out: dict[str, SourceFusion] = {}
    for src, recs in by_source.items():
        width = max(len(r.result.innovation) for r in recs)
        innov = np.full((len(recs), width), np.nan)
        for k, r in enumerate(recs):
            innov[k, : len(r.result.innovation)] = r.result.innovation
        out[src] = SourceFusion(
            t_obs_ns=np.array([r.t_obs_ns for r in recs], dtype=np.int64),
            nis=np.array([r.result.nis for r in recs], dtype=np.float64),
            test_ratio=np.array([r.result.test_ratio for r in recs], dtype=np.float64),
            accepted=np.array([r.result.accepted for r in recs], dtype=bool),
            dof=np.array([len(r.result.innovation) for r in recs], dtype=np.int64),
            innovation=innov,
        )
    return out


class DelayedFilter(Protocol):
    """A filter that runs at the delayed horizon (predict with IMU, fuse observations)."""

    @property
    def kinematics(self) -> Kinematics: ...

    @property
    def names(self) -> tuple[str, ...]: ...

    def predict(self, imu: ImuSample, dt_s: float) -> None: ...

    def can_fuse(self, obs: Sample) -> bool:
        """Whether this filter has a measurement model for ``obs`` (others are counted, not fused)."""
        ...

    def imu_biases(self) -> tuple[FloatArray, FloatArray]:
        """The gyro and accelerometer biases the output predictor must remove (zeros if none)."""
        ...

    def fuse(self, obs: Sample) -> FusionResult: ...

    def nav(self, t_ns: int, *, copy: bool = True) -> NavState:
        """The mean's position, velocity and attitude at ``t_ns``: copies, or with ``copy``
        false the filter's own arrays (to be read at once, before the filter moves on)."""
        ...

    @property
    def x(self) -> FloatArray: ...

    @property
    def P(self) -> FloatArray: ...


@dataclass(frozen=True, slots=True, kw_only=True)
class HorizonConfig:
    """Timing and output-predictor settings of the delayed-horizon core.

    ``max_delay_ns`` is the largest delay of any configured sensor; it fixes the IMU buffer.
    ``tau_vel_s`` and ``tau_pos_s`` are the output predictor's velocity and position
    time constants (PX4 ``EKF2_TAU_VEL``/``EKF2_TAU_POS``). With
    ``propagate_velocity_correction`` (our addition to PX4's scheme) a velocity correction
    also moves each buffered position by the correction times the entry's age, as the
    kinematics imply; ``False`` is PX4's constant correction.
    """

    imu_period_ns: int
    max_delay_ns: int
    tau_vel_s: float = 0.25
    tau_pos_s: float = 0.25
    output_correction: bool = True
    propagate_velocity_correction: bool = True
    max_observations_per_source: int = 1024
    max_fusion_log: int | None = None  # None: keep every fusion record (offline runs)

    def __post_init__(self) -> None:
        imu_buffer_length(max_delay_ns=self.max_delay_ns, imu_period_ns=self.imu_period_ns)
        require_positive(self, ("tau_vel_s", "tau_pos_s"))
        if self.max_fusion_log is not None and self.max_fusion_log < 1:
            raise EstimationError("HorizonConfig.max_fusion_log must be >= 1 or None")
        if self.max_observations_per_source < 1:
            raise EstimationError("HorizonConfig.max_observations_per_source must be >= 1")


@dataclass(frozen=True, slots=True)
class SourceStats:
    """What became of one observation source's samples (a snapshot of the
    :class:`SourceCounters` an estimator increments while it runs)."""

    received: int = 0
    fused: int = 0
    rejected_gate: int = 0
    rejected_too_old: int = 0
    rejected_unsupported: int = 0
    dropped_overflow: int = 0


@dataclass(slots=True)
class SourceCounters:
    """The running counters behind a :class:`SourceStats`."""

    received: int = 0
    fused: int = 0
    rejected_gate: int = 0
    rejected_too_old: int = 0
    rejected_unsupported: int = 0
    dropped_overflow: int = 0

    def snapshot(self) -> SourceStats:
        return SourceStats(
            self.received,
            self.fused,
            self.rejected_gate,
            self.rejected_too_old,
            self.rejected_unsupported,
            self.dropped_overflow,
        )


@dataclass(slots=True)
class _Counters:
    imu_received: int = 0
    imu_rejected_out_of_order: int = 0
    sources: dict[str, SourceCounters] = field(default_factory=dict)
    invalid: dict[str, int] = field(default_factory=dict)


_NEVER = 2**63 - 1  # (later than any time stamp)


class DelayedHorizonEstimator:
    """A filter at the delayed horizon plus PX4's output predictor at the current horizon.

    Implements the ``Estimator`` protocol: :meth:`push` any sample in arrival order,
    :meth:`output` for the current horizon, :meth:`delayed` for the fusion horizon.
    """

    def __init__(self, filt: DelayedFilter, config: HorizonConfig, *, t0_ns: int) -> None:
        self.filter = filt
        self.kin = filt.kinematics
        self.config = config
        self.buffer_length = imu_buffer_length(
            max_delay_ns=config.max_delay_ns, imu_period_ns=config.imu_period_ns
        )
        self._dt_nominal_s = dt = config.imu_period_ns * 1e-9
        self._half_period_ns = config.imu_period_ns // 2  # (an observation this near is due)
        # The output correction's position and velocity gains (PX4's dt / tau)
        self._pi_gains = (
            dt / min(max(config.tau_pos_s, dt), 10.0),
            dt / min(max(config.tau_vel_s, dt), 10.0),
        )
        self._imu_buffer: deque[tuple[ImuSample, float]] = deque()
        self._obs: dict[str, list[tuple[int, int, Sample]]] = {}
        self._earliest_obs_ns = _NEVER  # the earliest time of validity buffered in _obs
        self._seq = 0
        self._t_last_imu_ns = check_t_ns(t0_ns, "t0")
        self._t_delayed_ns = self._t_last_imu_ns
        self._fusion_started = False
        nav0 = filt.nav(self._t_last_imu_ns)
        # The output buffer is a ring of arrays so corrections apply to all of it at once.
        L = self.buffer_length
        self._ob_t = np.full(L, self._t_last_imu_ns, dtype=np.int64)
        self._ob_pos = np.tile(nav0.pos, (L, 1))
        self._ob_vel = np.tile(nav0.vel, (L, 1))
        self._ob_att = np.tile(nav0.att, (L, 1))
        self._ring = (self._ob_pos, self._ob_vel, self._ob_att)
        self._ob_t_now = self._t_last_imu_ns  # the time of the ring's head, as an int
        self._ob_head = 0
        self._ob_count = 1
        self._vel_err_integ = np.zeros_like(nav0.vel)
        self._pos_err_integ = np.zeros_like(nav0.pos)
        self._integrals = (self._pos_err_integ, self._vel_err_integ)
        self._dtheta_corr = np.zeros(3)
        self._last_gyro: FloatArray | None = None
        self._counters = _Counters()
        # Every fusion with its innovation and test ratio; a live loop bounds it (newest kept).
        self.fusion_log: deque[FusionRecord] = deque(maxlen=config.max_fusion_log)

    # -- time horizons -------------------------------------------------------------------
    @property
    def t_now_ns(self) -> int:
        """Time of the newest IMU sample (the current horizon)."""
        return self._t_last_imu_ns

    @property
    def t_delayed_ns(self) -> int:
        """Time the filter has reached (the delayed horizon)."""
        return self._t_delayed_ns

    def delayed_nav(self) -> NavState:
        return self.filter.nav(self._t_delayed_ns)

    def output_nav(self) -> NavState:
        """The output predictor's state (with no delay, the filter's own)."""
        if self.buffer_length == 1:
            return self.filter.nav(self._t_delayed_ns)
        h = self._ob_head
        return NavState(
            int(self._ob_t[h]),
            self._ob_pos[h].copy(),
            self._ob_vel[h].copy(),
            self._ob_att[h].copy(),
        )

    def delayed(self) -> StateEstimate:
        nav = self.delayed_nav()
        return self.kin.to_estimate(
            nav, self.filter.x.copy(), self.filter.names, self.filter.P.copy()
        )

    def output(self) -> StateEstimate:
        if self.buffer_length == 1:
            nav = self.filter.nav(self._t_delayed_ns)
        else:  # (the ring's rows themselves: to_estimate copies what it keeps)
            h = self._ob_head
            nav = NavState(self._ob_t_now, self._ob_pos[h], self._ob_vel[h], self._ob_att[h])
        # The output predictor carries the kinematics' state, not the filter's: its names.
        return self.kin.output_estimate(nav, self._last_gyro, self.filter.imu_biases()[0])

    # -- statistics ------------------------------------------------------------------------
    @property
    def imu_received(self) -> int:
        return self._counters.imu_received

    @property
    def imu_rejected_out_of_order(self) -> int:
        return self._counters.imu_rejected_out_of_order

    @property
    def rejected_invalid(self) -> dict[str, int]:
        """Raw readings refused at the boundary by :meth:`push_raw`, per sample type."""
        return dict(self._counters.invalid)

    def stats(self, source: str) -> SourceStats:
        """Counters of one observation source (zeros if it never sent anything)."""
        counters = self._counters.sources.get(source)
        return counters.snapshot() if counters is not None else SourceStats()

    def pending(self, source: str) -> int:
        """Observations of ``source`` buffered and not yet reached by the delayed horizon."""
        return len(self._obs.get(source, ()))

    @property
    def sources(self) -> tuple[str, ...]:
        return tuple(self._counters.sources)

    # -- input ---------------------------------------------------------------------------
    def push(self, sample: Sample) -> None:
        """Take one sample in arrival order. IMU samples advance time; others are buffered.

        Nothing a sample carries makes this raise: a late, out-of-order or unusable sample is
        rejected and counted (see :meth:`stats`). Only a non-sample is a programming error.
        """
        if type(sample) is ImuSample:  # (the common case, hundreds of times a second)
            self._push_imu(sample)
            return
        if not isinstance(sample, Sample) and not _is_stamped(sample):
            raise EstimationError(f"push() takes samples, got {type(sample).__name__}")
        if isinstance(sample, ImuSample):
            self._push_imu(sample)
        else:
            self._push_observation(sample)

    def push_raw(self, kind: Callable[..., Sample], /, **fields: Any) -> bool:
        """Build a sample of type ``kind`` from a driver's raw fields and push it.

        A reading the sample type refuses (a NaN, a wrong shape, a bad timestamp) is counted
        under :attr:`rejected_invalid` and dropped; the loop goes on. Returns whether it was
        taken.
        """
        try:
            sample = kind(**fields)
        except SampleError:
            name = getattr(kind, "__name__", str(kind))
            self._counters.invalid[name] = self._counters.invalid.get(name, 0) + 1
            return False
        self.push(sample)
        return True

    def _push_observation(self, obs: Sample) -> None:
        source = getattr(obs, "source", type(obs).__name__)
        stats = self._counters.sources.setdefault(source, SourceCounters())
        stats.received += 1
        if not self.filter.can_fuse(obs):
            stats.rejected_unsupported += 1
            return
        half_period = self.config.imu_period_ns // 2
        if self._fusion_started and obs.t_ns < self._t_delayed_ns - half_period:
            # The fusion horizon has passed this measurement's time of validity: its delay is
            # larger than the buffer allows (or it arrived out of order by more than that).
            stats.rejected_too_old += 1
            return
        queue = self._obs.setdefault(source, [])
        heapq.heappush(queue, (obs.t_ns, self._seq, obs))
        self._earliest_obs_ns = min(self._earliest_obs_ns, obs.t_ns)
        self._seq += 1
        if len(queue) > self.config.max_observations_per_source:
            # Keep the newest ones: drop the oldest time of validity.
            heapq.heappop(queue)
            stats.dropped_overflow += 1

    def _push_imu(self, imu: ImuSample) -> None:
        self._counters.imu_received += 1
        if imu.t_ns <= self._t_last_imu_ns:
            self._counters.imu_rejected_out_of_order += 1
            return
        dt_s = (imu.t_ns - self._t_last_imu_ns) * 1e-9
        self._t_last_imu_ns = imu.t_ns
        self._last_gyro = imu.gyro_rad_s
        self._imu_buffer.append((imu, dt_s))
        if self.buffer_length > 1:
            self._integrate_output(imu, dt_s)
        if len(self._imu_buffer) >= self.buffer_length:
            imu_d, dt_d = self._imu_buffer.popleft()
            self._step_delayed(imu_d, dt_d)
            if self.buffer_length > 1 and self.config.output_correction:
                self._correct_output()

    # -- delayed horizon -----------------------------------------------------------------
    def _step_delayed(self, imu: ImuSample, dt_s: float) -> None:
        # Observations nearest the horizon's current time that arrived while the horizon sat
        # there (at start-up, or just in time) are fused before it moves on. (Most steps have
        # nothing due: _fuse_due's own first test, without its call.)
        if self._t_delayed_ns + self._half_period_ns >= self._earliest_obs_ns:
            self._fuse_due()
        self.filter.predict(imu, dt_s)
        self._t_delayed_ns = imu.t_ns
        self._fusion_started = True
        if imu.t_ns + self._half_period_ns >= self._earliest_obs_ns:
            self._fuse_due()

    def _fuse_due(self) -> None:
        """Fuse, in time order, every buffered observation nearest the delayed horizon's time."""
        limit = self._t_delayed_ns + self._half_period_ns
        if limit < self._earliest_obs_ns:  # (nothing buffered is due: most IMU steps)
            return
        due: list[tuple[int, int, Sample]] = []
        for queue in self._obs.values():
            while queue and queue[0][0] <= limit:
                due.append(heapq.heappop(queue))
        self._earliest_obs_ns = min((q[0][0] for q in self._obs.values() if q), default=_NEVER)
        due.sort()
        for t_obs, _, obs in due:
            result = self.filter.fuse(obs)
            source = getattr(obs, "source", type(obs).__name__)
            stats = self._counters.sources[source]
            if result.accepted:
                stats.fused += 1
            else:
                stats.rejected_gate += 1
            self.fusion_log.append(
                FusionRecord(
                    t_obs_ns=t_obs, t_fused_ns=self._t_delayed_ns, source=source, result=result
                )
            )

    # -- output predictor ----------------------------------------------------------------
    def _integrate_output(self, imu: ImuSample, dt_s: float) -> None:
        h = self._ob_head
        h1 = h + 1 if h + 1 < self.buffer_length else 0
        # (the filter's latest bias estimates, as PX4 does)
        self.kin.integrate_ring(
            self._ring, h, h1, imu, self.filter.imu_biases(), dt_s, self._dtheta_corr
        )
        self._ob_head = h1
        if self._ob_count < self.buffer_length:
            self._ob_count += 1
        self._ob_t[h1] = self._ob_t_now = imu.t_ns

    def _correct_output(self) -> None:
        L = self.buffer_length
        oldest = (self._ob_head + 1) % L if self._ob_count == L else 0
        if self._ob_t[oldest] != self._t_delayed_ns:
            # The buffers are aligned by construction; a mismatch is a bug, not bad input.
            raise EstimationError(
                f"output buffer at {self._ob_t[oldest]} ns but delayed horizon at "
                f"{self._t_delayed_ns} ns"
            )
        nav = self.filter.nav(self._t_delayed_ns, copy=False)  # (read by the correction alone)
        dt = self._dt_nominal_s
        # Attitude: a delta-angle correction with PX4's gain 0.5 * dt / delay.
        time_delay_s = max((self._t_last_imu_ns - self._t_delayed_ns) * 1e-9, dt)
        att_gain = 0.5 * dt / time_delay_s
        # Velocity and position: proportional-integral, applied to the whole buffer.
        pos_gain, vel_gain = self._pi_gains
        gains = (att_gain, pos_gain, vel_gain)
        self._dtheta_corr = self.kin.correct_ring(
            self._ring, self._ob_t, oldest, nav, self._integrals, gains,
            self.config.propagate_velocity_correction,
        )  # fmt: skip


@njit
def _pi_correct(
    ob_t: NDArray[np.int64], ob_pos: FloatArray, ob_vel: FloatArray, oldest: int,
    pos: FloatArray, vel: FloatArray, pos_integ: FloatArray, vel_integ: FloatArray,
    pos_gain: float, vel_gain: float, propagate: bool,
) -> None:  # fmt: skip
    """The output predictor's velocity and position correction, in place on the whole ring:
    the error at the delayed horizon (the ring's ``oldest`` entry against the filter's
    ``pos``, ``vel``) through a proportional-integral gain (PX4's). With ``propagate``, a
    velocity change at the delayed horizon also moves every later state by that change times
    its age; PX4 leaves this to later integration."""
    d = ob_pos.shape[1]
    vel_corr = np.empty(d)
    pos_corr = np.empty(d)
    for k in range(d):
        vel_err = vel[k] - ob_vel[oldest, k]
        pos_err = pos[k] - ob_pos[oldest, k]
        vel_integ[k] += vel_err
        pos_integ[k] += pos_err
        vel_corr[k] = vel_err * vel_gain + vel_integ[k] * (vel_gain**2 * 0.1)
        pos_corr[k] = pos_err * pos_gain + pos_integ[k] * (pos_gain**2 * 0.1)
    t0 = ob_t[oldest]
    for i in range(ob_pos.shape[0]):
        age_s = (ob_t[i] - t0) * 1e-9
        for k in range(d):
            ob_vel[i, k] += vel_corr[k]
            ob_pos[i, k] += pos_corr[k] + age_s * vel_corr[k] if propagate else pos_corr[k]


def _is_stamped(sample: object) -> bool:
    """A message type of the user's own (a new sensor's, fused through a model registered
    with the filter): a dataclass with an integer ``t_ns``."""
    return dataclasses.is_dataclass(sample) and isinstance(getattr(sample, "t_ns", None), int)
