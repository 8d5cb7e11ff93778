"""Smooth 6-DoF motions through poses, and the IMU they make.

:class:`SplineMotion` fits a least-squares (smoothing, not interpolating) quintic B-spline to a
trajectory's positions and another to its sign-continuous quaternion components, normalised.
Real ground truth (EuRoC's Vicon at 200 Hz, TUM-VI's at 20 Hz) is noisy: an interpolating
spline through it would make absurd accelerations. Velocity, acceleration, body rate and body
angular acceleration are the splines' analytic derivatives, so the IMU
:func:`synthesize_imu` makes from them integrates back to the spline's own poses.

Body rate from the normalised quaternion ``q`` (xyzw) and its derivative:
``omega_B = 2 vec(conj(q) ⊗ q_dot)``, and ``alpha_B = 2 vec(conj(q) ⊗ q_ddot)`` (the scalar
``conj(q_dot) ⊗ q_dot`` drops out of the vector part).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace

import numpy as np
from numpy.random import Generator
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import BSpline, make_lsq_spline
from scipy.linalg import cho_solve_banded, cholesky_banded
from scipy.spatial.transform import Rotation

from quadnav.errors import SimError
from quadnav.geometry.trajectory import Trajectory
from quadnav.messages import ImuSample
from quadnav.rig import ImuNoiseModel
from quadnav.sim.sensors import ImuErrors
from quadnav.units import GRAVITY_M_S2, NS_PER_S, s_to_ns

__all__ = [
    "ImuNoiseModel",
    "ImuSeries",
    "MotionFit",
    "SplineMotion",
    "imu_errors",
    "synthesize_imu",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Degree of both splines: quintic, so acceleration and body rate are C2 and jerk continuous.
DEGREE = 5
#: The default knot spacing is at least this, and at least this many pose periods.
MIN_KNOT_SPACING_S = 0.1
POSES_PER_KNOT = 4
#: Rows a motion evaluates, or a sampled fit takes, at once: the splines' temporaries stay a few
#: MB however long the span (30 minutes of 1 kHz poses in one piece took ~500 MB).
CHUNK_ROWS = 32768
#: A sampler of poses: ``p_W_B`` (N, 3) and ``q_W_B_xyzw`` (N, 4) at ``t_ns`` (N,).
PoseSampler = Callable[[NDArray[np.int64]], tuple[NDArray[np.float64], NDArray[np.float64]]]


def imu_errors(noise: ImuNoiseModel, rate_hz: float) -> ImuErrors:
    """The per-sample errors of ``noise`` at ``rate_hz``: white noise ``density * sqrt(rate_hz)``."""
    sq = math.sqrt(rate_hz)
    return ImuErrors(
        gyro_sigma_rad_s=noise.gyro_noise_density * sq,
        accel_sigma_m_s2=noise.accel_noise_density * sq,
        gyro_bias_rw_rad_s_sqrt_s=noise.gyro_random_walk,
        accel_bias_rw_m_s2_sqrt_s=noise.accel_random_walk,
        gyro_bias0_rad_s=noise.gyro_bias0_rad_s,
        accel_bias0_m_s2=noise.accel_bias0_m_s2,
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class MotionFit:
    """How closely a motion follows poses (those inside its trimmed span)."""

    n_poses: int
    rms_position_m: float
    max_position_m: float
    rms_rotation_deg: float
    max_rotation_deg: float


def _checked_poses(
    t_ns: ArrayLike, p_W_B: ArrayLike, q_W_B_xyzw: ArrayLike
) -> tuple[IntArray, FloatArray, FloatArray]:
    t = np.asarray(t_ns)
    if t.ndim != 1 or not np.issubdtype(t.dtype, np.integer):
        raise SimError("motion: pose times must be a 1-D array of integer t_ns")
    n = len(t)
    p, q = np.asarray(p_W_B, dtype=np.float64), np.asarray(q_W_B_xyzw, dtype=np.float64)
    if p.shape != (n, 3) or q.shape != (n, 4):
        raise SimError(f"motion: need p (N, 3) and q (N, 4) for N = {n}, got {p.shape}, {q.shape}")
    if n < 2:
        raise SimError(f"motion: need at least 2 poses, got {n}")
    if np.any(np.diff(t) <= 0):
        k = int(np.argmax(np.diff(t) <= 0))
        raise SimError(f"motion: pose times must increase (pose {k + 1} is not after pose {k})")
    if not (np.isfinite(p).all() and np.isfinite(q).all()):
        k = int(np.argmax(~(np.isfinite(p).all(axis=1) & np.isfinite(q).all(axis=1))))
        raise SimError(f"motion: pose {k} holds NaN or infinity")
    if np.linalg.norm(q, axis=1).min() < 1e-9:
        raise SimError("motion: a quaternion is zero")
    return t.astype(np.int64), p, q


def _knots(t_s: FloatArray, spacing_s: float) -> FloatArray:
    """Uniform interior knots ``spacing_s`` apart, the ends repeated (clamped). Every knot span
    must hold a pose, or the least-squares problem has no unique answer there."""
    span = float(t_s[-1])
    n_spans = max(1, round(span / spacing_s))
    interior = np.linspace(0.0, span, n_spans + 1)[1:-1]
    counts = np.histogram(t_s, bins=np.linspace(0.0, span, n_spans + 1))[0]
    if len(t_s) < n_spans + DEGREE + 1:
        raise SimError(
            f"motion: {len(t_s)} poses over {span:.3g} s, too few for knot_spacing_s = "
            f"{spacing_s:g} (a quintic on {n_spans} knot spans needs {n_spans + DEGREE + 1}): "
            "raise knot_spacing_s"
        )
    if counts.min() == 0:
        where = int(np.argmin(counts))
        raise SimError(
            f"motion: no pose from {where * span / n_spans:.3g} s to "
            f"{(where + 1) * span / n_spans:.3g} s, a gap longer than knot_spacing_s = "
            f"{spacing_s:g}: raise knot_spacing_s"
        )
    return np.concatenate([np.zeros(DEGREE + 1), interior, np.full(DEGREE + 1, span)])


def _knots_of_span(span_s: float, spacing_s: float) -> FloatArray:
    """:func:`_knots` of poses from 0 to ``span_s`` that fill every knot span."""
    n_spans = max(1, round(span_s / spacing_s))
    interior = np.linspace(0.0, span_s, n_spans + 1)[1:-1]
    return np.concatenate([np.zeros(DEGREE + 1), interior, np.full(DEGREE + 1, span_s)])


class _NormalEquations:
    """The banded normal equations of a least-squares spline on ``knots``, summed chunk by
    chunk (the lower band, as :func:`scipy.linalg.cholesky_banded` takes it), then solved."""

    def __init__(self, knots: FloatArray, *, width: int) -> None:
        self.knots = knots
        self.n = len(knots) - DEGREE - 1
        self.band = np.zeros((DEGREE + 1, self.n))
        self.rhs = np.zeros((self.n, width))

    def add(self, x: FloatArray, y: FloatArray) -> None:
        A = BSpline.design_matrix(x, self.knots, DEGREE).tocsr()
        AtA = (A.T @ A).tocsr()
        for d in range(DEGREE + 1):
            self.band[d, : self.n - d] += AtA.diagonal(-d)
        self.rhs += np.asarray(A.T @ y)

    def solve(self) -> FloatArray:
        try:
            factor = cholesky_banded(self.band, lower=True)
            return np.asarray(cho_solve_banded((factor, True), self.rhs), dtype=np.float64)
        except (ValueError, np.linalg.LinAlgError) as exc:
            raise SimError(f"motion: the spline fit failed ({exc}); raise knot_spacing_s") from None


def _lsq(t_s: FloatArray, y: FloatArray, knots: FloatArray) -> BSpline:
    """The least-squares spline through ``y``, by its banded normal equations: linear in the
    poses (scipy's default QR took 45 s for 6 minutes of 1 kHz poses, ~20 minutes for 30; a
    30-minute dataset's motion now takes seconds). Every knot span holds a pose (``_knots``), so
    the band is positive definite."""
    try:
        return make_lsq_spline(t_s, y, knots, k=DEGREE, method="norm-eq")
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise SimError(f"motion: the spline fit failed ({exc}); raise knot_spacing_s") from None


def _continuous_quaternions(q: FloatArray) -> FloatArray:
    """Unit quaternions with the sign of each chosen next to the one before (q and -q are the
    same rotation; a spline through a sign flip would pass through zero)."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    flips = np.sum(q[1:] * q[:-1], axis=1) < 0.0
    sign = np.cumprod(np.concatenate([[1.0], np.where(flips, -1.0, 1.0)]))
    return np.asarray(q * sign[:, None], dtype=np.float64)


def _unit_derivatives(s: FloatArray, ds: FloatArray, dds: FloatArray) -> list[FloatArray]:
    """``n = s / |s|`` and its first two time derivatives, from those of ``s``."""
    r = np.linalg.norm(s, axis=1, keepdims=True)
    n = s / r
    dr = np.sum(n * ds, axis=1, keepdims=True)
    dn = ds / r - s * dr / r**2
    ddr = np.sum(dn * ds + n * dds, axis=1, keepdims=True)
    ddn = dds / r - 2.0 * ds * dr / r**2 - s * ddr / r**2 + 2.0 * s * dr**2 / r**3
    return [n, dn, ddn]


def _conj_product_vec(q: FloatArray, d: FloatArray) -> FloatArray:
    """``2 vec(conj(q) ⊗ d)`` for xyzw rows: the body rate when ``d`` is ``q_dot``. (scipy's
    Rotation has no product with a quaternion's derivative, which is not a rotation.)"""
    v, w = q[:, :3], q[:, 3:4]
    dv, dw = d[:, :3], d[:, 3:4]
    return np.asarray(2.0 * (w * dv - dw * v - np.cross(v, dv)), dtype=np.float64)


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class SplineMotion:
    """A C2 (quintic) motion of the body in the world, evaluated at any ``t_ns`` in
    ``[t_start_ns, t_end_ns]`` (the fitted span less ``trim_s`` at each end, where a
    least-squares spline is held by poses on one side only)."""

    t0_ns: int
    position: BSpline
    quaternion: BSpline
    t_start_ns: int
    t_end_ns: int
    knot_spacing_s: float
    name: str = ""
    poses: Trajectory | None = None  # what it was fitted to (``fit_to(motion.poses)``)

    @classmethod
    def fit(
        cls,
        traj: Trajectory,
        *,
        knot_spacing_s: float | None = None,
        trim_s: float | None = None,
    ) -> SplineMotion:
        """Least-squares quintic splines through ``traj``'s poses. ``knot_spacing_s`` (None:
        the larger of 0.1 s and 4 pose periods) sets how much is smoothed; ``trim_s`` (None:
        two knot spacings) how much of each end is left out of the span."""
        motion = cls.from_arrays(
            traj.t_ns,
            traj.p_W_B,
            traj.q_W_B_xyzw,
            knot_spacing_s=knot_spacing_s,
            trim_s=trim_s,
            name=traj.name,
        )
        return replace(motion, poses=traj)

    @classmethod
    def from_arrays(
        cls,
        t_ns: ArrayLike,
        p_W_B: ArrayLike,
        q_W_B_xyzw: ArrayLike,
        *,
        knot_spacing_s: float | None = None,
        trim_s: float | None = None,
        name: str = "",
    ) -> SplineMotion:
        """:meth:`fit` on arrays: ``t_ns`` (N,) integers, ``p_W_B`` (N, 3), ``q_W_B_xyzw`` (N, 4)."""
        t, p, q = _checked_poses(t_ns, p_W_B, q_W_B_xyzw)
        t0 = int(t[0])
        t_s = np.asarray((t - t0) / NS_PER_S, dtype=np.float64)
        if knot_spacing_s is None:
            knot_spacing_s = max(
                MIN_KNOT_SPACING_S, POSES_PER_KNOT * float(np.median(np.diff(t_s)))
            )
        if not (math.isfinite(knot_spacing_s) and knot_spacing_s > 0.0):
            raise SimError(f"motion knot_spacing_s must be finite and > 0, got {knot_spacing_s}")
        knots = _knots(t_s, knot_spacing_s)
        trim = 2.0 * knot_spacing_s if trim_s is None else trim_s
        if not (math.isfinite(trim) and trim >= 0.0 and 2.0 * trim < t_s[-1]):
            raise SimError(
                f"motion: the poses span {t_s[-1]:.3g} s, too short to trim trim_s = {trim:g} s "
                f"off each end (by default 2 x knot_spacing_s = {knot_spacing_s:g} s)"
            )
        return cls(
            t0_ns=t0,
            position=_lsq(t_s, p, knots),
            quaternion=_lsq(t_s, _continuous_quaternions(q), knots),
            t_start_ns=t0 + s_to_ns(trim),
            t_end_ns=int(t[-1]) - s_to_ns(trim),
            knot_spacing_s=float(knot_spacing_s),
            name=name,
        )

    @classmethod
    def fit_sampled(
        cls,
        sample: PoseSampler,
        t_start_ns: int,
        t_end_ns: int,
        period_ns: int,
        *,
        knot_spacing_s: float,
        name: str = "",
    ) -> SplineMotion:
        """:meth:`from_arrays` (no trim) on the poses ``sample`` gives at ``t_start_ns + k
        period_ns`` before ``t_end_ns``, taken :data:`CHUNK_ROWS` at a time into the normal
        equations, so that the memory does not grow with the span (the same spline, to
        floating-point round-off). Every knot span holds a pose: the period is below the
        spacing."""
        n = -(-(int(t_end_ns) - int(t_start_ns)) // int(period_ns))
        if not (period_ns > 0 and n >= 2 and period_ns < s_to_ns(knot_spacing_s)):
            raise SimError(
                f"motion: {n} poses {period_ns} ns apart, too few or too sparse for "
                f"knot_spacing_s = {knot_spacing_s:g}"
            )
        t0, t_last = int(t_start_ns), int(t_start_ns) + (n - 1) * int(period_ns)
        knots = _knots_of_span((t_last - t0) / NS_PER_S, knot_spacing_s)
        normal = _NormalEquations(knots, width=7)
        q_before: FloatArray | None = None
        for k in range(0, n, CHUNK_ROWS):
            t = t0 + period_ns * np.arange(k, min(k + CHUNK_ROWS, n), dtype=np.int64)
            p, q = sample(t)
            if q_before is not None:  # the sign continues from the chunk before
                q = _continuous_quaternions(np.vstack([q_before, q]))[1:]
            else:
                q = _continuous_quaternions(q)
            q_before = q[-1:]
            normal.add(np.asarray((t - t0) / NS_PER_S, dtype=np.float64), np.hstack([p, q]))
        c = normal.solve()
        return cls(
            t0_ns=t0,
            position=BSpline(knots, np.ascontiguousarray(c[:, :3]), DEGREE),
            quaternion=BSpline(knots, np.ascontiguousarray(c[:, 3:]), DEGREE),
            t_start_ns=t0,
            t_end_ns=t_last,
            knot_spacing_s=float(knot_spacing_s),
            name=name,
        )

    @property
    def knots_ns(self) -> IntArray:
        """The interior knots (where a quintic's fifth derivative may jump)."""
        k = np.unique(self.position.t)[1:-1]
        return np.asarray(self.t0_ns + np.rint(k * NS_PER_S), dtype=np.int64)

    def _t(self, t_ns: ArrayLike) -> FloatArray:
        t = np.atleast_1d(np.asarray(t_ns))
        if not np.issubdtype(t.dtype, np.integer):
            raise SimError(f"motion {self.name!r}: t_ns must be integer nanoseconds")
        if t.size and (t.min() < self.t_start_ns or t.max() > self.t_end_ns):
            raise SimError(
                f"motion {self.name!r}: t_ns {int(t.min())}..{int(t.max())} lies outside its "
                f"span {self.t_start_ns}..{self.t_end_ns}"
            )
        return np.asarray((t.astype(np.int64) - self.t0_ns) / NS_PER_S, dtype=np.float64)

    def _rows(
        self, t_ns: ArrayLike, width: int, fn: Callable[[FloatArray], FloatArray]
    ) -> FloatArray:
        """``fn`` (a pointwise function of the spline time) at ``t_ns``, :data:`CHUNK_ROWS`
        rows at a time into one (N, ``width``) array: the same numbers as in one piece."""
        t = self._t(t_ns)
        out = np.empty((len(t), width), dtype=np.float64)
        for s in range(0, len(t), CHUNK_ROWS):
            out[s : s + CHUNK_ROWS] = fn(t[s : s + CHUNK_ROWS])
        return out

    def _quaternion(self, t_s: FloatArray, order: int) -> list[FloatArray]:
        """The unit quaternion and its derivatives up to ``order`` (at most 2)."""
        s = np.asarray(self.quaternion(t_s), dtype=np.float64)
        if order == 0:
            return [s / np.linalg.norm(s, axis=1, keepdims=True)]
        ds, dds = (np.asarray(self.quaternion(t_s, nu=k), dtype=np.float64) for k in (1, 2))
        return _unit_derivatives(s, ds, dds)[: order + 1]

    def _derivative(self, nu: int) -> Callable[[FloatArray], FloatArray]:
        return lambda t: np.asarray(self.position(t, nu=nu), dtype=np.float64)

    def pose(self, t_ns: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``p_W_B`` (N, 3) and ``q_W_B_xyzw`` (N, 4) at ``t_ns``."""
        p = self._rows(t_ns, 3, self._derivative(0))
        return p, self._rows(t_ns, 4, lambda t: self._quaternion(t, 0)[0])

    def velocity(self, t_ns: ArrayLike) -> FloatArray:
        """``v_W_B`` (N, 3), m/s."""
        return self._rows(t_ns, 3, self._derivative(1))

    def acceleration(self, t_ns: ArrayLike) -> FloatArray:
        """``a_W_B`` (N, 3), m/s^2 (kinematic: no gravity)."""
        return self._rows(t_ns, 3, self._derivative(2))

    def jerk(self, t_ns: ArrayLike) -> FloatArray:
        """The world acceleration's rate (N, 3), m/s^3."""
        return self._rows(t_ns, 3, self._derivative(3))

    def angular_rate_B(self, t_ns: ArrayLike) -> FloatArray:
        """Body rate ``omega_B`` (N, 3), rad/s, body FLU."""
        return self._rows(t_ns, 3, lambda t: _conj_product_vec(*self._quaternion(t, 1)))

    def angular_accel_B(self, t_ns: ArrayLike) -> FloatArray:
        """Body angular acceleration (N, 3), rad/s^2: the derivative of ``angular_rate_B``."""

        def alpha(t: FloatArray) -> FloatArray:
            q, _, ddq = self._quaternion(t, 2)
            return _conj_product_vec(q, ddq)

        return self._rows(t_ns, 3, alpha)

    def fit_to(self, traj: Trajectory) -> MotionFit:
        """Residuals against ``traj``'s poses inside the span: position and rotation angle."""
        t = np.asarray(traj.t_ns, dtype=np.int64)
        inside = (t >= self.t_start_ns) & (t <= self.t_end_ns)
        if not inside.any():
            raise SimError(f"motion {self.name!r}: no pose of the trajectory inside its span")
        p, q = self.pose(t[inside])
        dp = np.linalg.norm(p - np.asarray(traj.p_W_B)[inside], axis=1)
        R_err = Rotation.from_quat(q).inv() * Rotation.from_quat(traj.q_W_B_xyzw[inside])
        ang = np.degrees(R_err.magnitude())
        return MotionFit(
            n_poses=int(inside.sum()),
            rms_position_m=float(np.sqrt(np.mean(dp**2))),
            max_position_m=float(dp.max()),
            rms_rotation_deg=float(np.sqrt(np.mean(ang**2))),
            max_rotation_deg=float(ang.max()),
        )


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class ImuSeries:
    """IMU samples as arrays (N rows): the stamp each carries (``t_ns``: the true time plus the
    IMU clock's offset), the true time it measured, gyro (rad/s, body FLU) and specific force
    (m/s^2), and the true biases each carries (a dataset's ``bw*``, ``ba*``)."""

    t_ns: IntArray
    t_true_ns: IntArray
    gyro_rad_s: FloatArray
    accel_m_s2: FloatArray
    gyro_bias_rad_s: FloatArray
    accel_bias_m_s2: FloatArray

    def __len__(self) -> int:
        return len(self.t_ns)

    def samples(self) -> Iterator[ImuSample]:
        """The rows as :class:`~quadnav.messages.ImuSample`, in time order."""
        for k in range(len(self.t_ns)):
            yield ImuSample(
                t_ns=int(self.t_ns[k]), gyro_rad_s=self.gyro_rad_s[k], accel_m_s2=self.accel_m_s2[k]
            )


def _imu_times(
    motion: SplineMotion, rate_hz: float, t_start_ns: int | None, t_end_ns: int | None
) -> IntArray:
    if not (math.isfinite(rate_hz) and rate_hz > 0.0):
        raise SimError(f"IMU rate_hz must be finite and > 0, got {rate_hz}")
    period_ns = s_to_ns(1.0 / rate_hz)
    start = motion.t_start_ns if t_start_ns is None else int(t_start_ns)
    end = motion.t_end_ns if t_end_ns is None else int(t_end_ns)
    if not motion.t_start_ns <= start < end <= motion.t_end_ns:
        raise SimError(
            f"IMU t_start_ns..t_end_ns ({start}..{end}) must be an interval inside the motion's "
            f"span {motion.t_start_ns}..{motion.t_end_ns}"
        )
    n = (end - start) // period_ns + 1
    return start + period_ns * np.arange(n, dtype=np.int64)


def _exact_imu(
    motion: SplineMotion, t_true: IntArray, r: FloatArray, gravity_m_s2: float
) -> tuple[FloatArray, FloatArray]:
    """Gyro and specific force without errors at ``t_true`` (see :func:`synthesize_imu`)."""
    _, q = motion.pose(t_true)
    w = motion.angular_rate_B(t_true)
    a = motion.acceleration(t_true)
    a[:, 2] += gravity_m_s2
    f = Rotation.from_quat(q).apply(a, inverse=True)
    if r.any():
        f = f + np.cross(motion.angular_accel_B(t_true), r) + np.cross(w, np.cross(w, r))
    return w, f


def synthesize_imu(
    motion: SplineMotion,
    *,
    rate_hz: float,
    noise: ImuNoiseModel | None,
    rng: Generator | None = None,
    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
    gravity_m_s2: float = GRAVITY_M_S2,
    t_offset_ns: int = 0,
    t_start_ns: int | None = None,
    t_end_ns: int | None = None,
) -> ImuSeries:
    """The IMU an ideal point sensor at ``lever_arm_m`` (body FLU) on ``motion`` reads at
    ``rate_hz``: gyro ``omega_B``, specific force ``R_W_B^T (a_W + g e_z) + alpha_B x r +
    omega_B x (omega_B x r)``, plus ``noise`` (None: exact). Samples measure the true times
    ``t_start_ns + k / rate_hz`` (default: the whole span) and carry stamps ``t_offset_ns`` later
    (the IMU clock's offset)."""
    if noise is not None and rng is None:
        raise SimError("synthesize_imu: an IMU noise model needs an rng")
    r = np.asarray(lever_arm_m, dtype=np.float64)
    if r.shape != (3,) or not np.isfinite(r).all():
        raise SimError(f"IMU lever_arm_m must be 3 finite numbers, got {lever_arm_m}")
    t_true = _imu_times(motion, rate_hz, t_start_ns, t_end_ns)
    w, f = np.empty((len(t_true), 3)), np.empty((len(t_true), 3))
    for s in range(0, len(t_true), CHUNK_ROWS):  # a few MB at a time, however long the span
        w[s : s + CHUNK_ROWS], f[s : s + CHUNK_ROWS] = _exact_imu(
            motion, t_true[s : s + CHUNK_ROWS], r, gravity_m_s2
        )
    bg, ba = np.zeros_like(w), np.zeros_like(w)
    if noise is not None and rng is not None:
        err = imu_errors(noise, rate_hz).draw(len(t_true), 1.0 / rate_hz, rng)
        bg, ba = err.gyro_bias_rad_s, err.accel_bias_m_s2
        w += bg  # in place, as (w + bg) + noise: the same sums, no copies
        w += err.gyro_noise_rad_s
        f += ba
        f += err.accel_noise_m_s2
    return ImuSeries(
        t_ns=t_true + int(t_offset_ns),
        t_true_ns=t_true,
        gyro_rad_s=w,
        accel_m_s2=f,
        gyro_bias_rad_s=bg,
        accel_bias_m_s2=ba,
    )
