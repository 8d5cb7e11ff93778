"""A reference for fusing a drifting odometry with position fixes (issue 25's GPS + VIO): what
a simple causal fusion, tuned with hindsight, makes of this flight's odometry and fixes.

Given the odometry's own position error over the flight (its world put on the truth at its
first state, as a vehicle starting it where it stands would), fixes of known white noise at a
known rate are drawn, and a Kalman filter that models the odometry's error as a random walk per
axis estimates that error from them; the fused position is the odometry less the estimate. The
walk's rate is the one, of half-decades from 1e-6 to 1 m^2/s, that suits this flight best
(chosen with hindsight), and the result is averaged over draws of the fixes' noise.

It is not a bound. The navigation EKF also has the GPS's velocity, the IMU between fixes, and a
drift model with the odometry's heading and scale; on ``outdoor_vio_gps_odometry``'s shortcut,
whose drift is that model, the EKF does better (2026-12-04 session 21 page). What it says is how
far a fusion's error is from that of a position-only filter that knows how fast its odometry
drifts: when the EKF is well above it (the ideal VIO's flights), the EKF takes more from the
fixes than this odometry's drift calls for.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import EvalError

__all__ = ["RATES_M2_S", "FusionReference", "random_walk_fusion_reference"]

FloatArray = NDArray[np.float64]

#: The drift rates tried (m^2/s an axis): half-decades from 1e-6 to 1.
RATES_M2_S: tuple[float, ...] = tuple(10.0 ** (k / 2.0) for k in range(-12, 1))


@dataclass(frozen=True, slots=True)
class FusionReference:
    """The reference's fused position RMSE (m), the odometry alone's on the same states, and the
    random walk's rate that gave it (m^2/s an axis; 0: no rate did better than the odometry
    alone)."""

    rmse_m: float
    alone_m: float
    rate_m2_s: float


def random_walk_fusion_reference(
    t_ns: NDArray[np.int64],
    err_m: FloatArray,
    fix_sigma_m: Sequence[float],
    fix_rate_hz: float,
    *,
    outages_s: Sequence[tuple[float, float]] = (),
    draws: int = 20,
    seed: int = 0,
    rates_m2_s: Sequence[float] = RATES_M2_S,
) -> FusionReference:
    """The reference for an odometry whose position error is ``err_m`` (N, 3) at times ``t_ns``
    (N, increasing; zero error at the first, where it was put on the truth), fused with fixes
    of noise ``fix_sigma_m`` (east, north, up) every ``1 / fix_rate_hz`` seconds from the first
    time, none inside ``outages_s`` ([start, end) in seconds of the same clock). Each fix is taken at the
    first odometry time at or after it. ``draws`` noise draws (from ``seed``) per rate."""
    t_int = np.asarray(t_ns)
    if t_int.ndim != 1 or not np.issubdtype(t_int.dtype, np.integer):
        raise EvalError(f"the odometry's times must be integer ns, got {t_int.dtype} {t_int.shape}")
    t = t_int.astype(np.float64) * 1e-9
    e = np.asarray(err_m, dtype=np.float64)
    sigma = np.asarray(fix_sigma_m, dtype=np.float64)
    if t.ndim != 1 or e.shape != (len(t), 3) or len(t) < 2:
        raise EvalError(f"the odometry's errors must be (N, 3) at N >= 2 times, got {e.shape}")
    if not (np.isfinite(t).all() and np.isfinite(e).all()) or (np.diff(t) <= 0).any():
        raise EvalError("the odometry's times must increase and its errors be finite")
    if sigma.shape != (3,) or not (np.isfinite(sigma).all() and (sigma > 0).all()):
        raise EvalError(f"the fixes' sigmas must be 3 positive numbers, got {sigma.tolist()}")
    if not (math.isfinite(fix_rate_hz) and fix_rate_hz > 0) or draws < 1:
        raise EvalError(f"the fix rate must be > 0 Hz and draws >= 1, got {fix_rate_hz}, {draws}")
    t_fix = np.arange(t[0], t[-1], 1.0 / fix_rate_hz)
    for a, b in outages_s:
        t_fix = t_fix[(t_fix < a) | (t_fix >= b)]
    at = np.searchsorted(t, t_fix)  # (the first odometry state at or after each fix)
    fixed = np.zeros(len(t), dtype=bool)
    fixed[np.unique(at[at < len(t)])] = True
    noise = np.random.default_rng(seed).standard_normal((draws, len(t), 3)) * sigma
    alone = float(np.sqrt(np.mean(np.sum(e**2, axis=1))))
    best = FusionReference(alone, alone, 0.0)
    dt = np.diff(t, prepend=t[0])
    for q in rates_m2_s:
        rmse = _fused_rmse(e, noise, fixed, dt, float(q), sigma**2)
        if rmse < best.rmse_m:
            best = FusionReference(rmse, alone, float(q))
    return best


def _fused_rmse(
    e: FloatArray, noise: FloatArray, fixed: NDArray[np.bool_], dt: FloatArray, q: float,
    var: FloatArray,
) -> float:  # fmt: skip
    """The fused error's RMSE over states and draws: the random walk's filter, started known
    (variance 0, estimate 0), updated by ``e - noise`` where ``fixed``."""
    d = np.zeros((noise.shape[0], 3))
    P = np.zeros(3)
    sq = 0.0
    for i in range(len(e)):
        P = P + q * dt[i]
        if fixed[i]:
            K = P / (P + var)
            d += K * (e[i] - noise[:, i] - d)
            P = (1.0 - K) * P
        sq += float(np.sum((e[i] - d) ** 2))
    return math.sqrt(sq / (len(e) * noise.shape[0]))
