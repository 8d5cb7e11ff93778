"""Error metrics: APE, RPE (frames, seconds or metres), their statistics, NEES and NIS.

APE and RPE follow the definitions evo uses, so results agree with it: APE compares matched
poses after alignment; RPE compares relative motions ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)``
(Q reference, P estimate) over pairs of poses a step apart.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import EvalError
from quadnav.geometry.trajectory import Trajectory
from quadnav.units import s_to_ns

__all__ = [
    "ErrorStats",
    "PoseRelation",
    "RpeUnit",
    "ape",
    "ape_matrices",
    "error_stats",
    "nees",
    "nis",
    "pose_errors",
    "position_nees",
    "rpe",
    "rpe_matrices",
    "rpe_pairs",
    "settling_time_s",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
PoseRelation = Literal["trans", "rot", "full"]
RpeUnit = Literal["frames", "seconds", "metres"]


@dataclass(frozen=True, slots=True, kw_only=True)
class ErrorStats:
    """rmse, mean, median, std, min, max and sse of an error array (as evo reports them)."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float

    @classmethod
    def of(cls, errors: FloatArray) -> ErrorStats:
        e = np.asarray(errors, dtype=np.float64)
        if e.ndim != 1 or len(e) == 0:
            raise EvalError("statistics need a non-empty 1-D error array")
        return cls(
            rmse=float(np.sqrt(np.mean(e**2))),
            mean=float(np.mean(e)),
            median=float(np.median(e)),
            std=float(np.std(e)),
            min=float(np.min(e)),
            max=float(np.max(e)),
            sse=float(np.sum(e**2)),
        )

    def as_dict(self) -> dict[str, float]:
        """The statistics by evo's names, in evo's order (the shape ``metrics.json`` keeps)."""
        return asdict(self)


def error_stats(errors: FloatArray) -> dict[str, float]:
    """:class:`ErrorStats` of an error array, as a mapping by evo's names."""
    return ErrorStats.of(errors).as_dict()


#: Pairs whose relative errors :func:`rpe` makes at once.
RPE_CHUNK = 8192


def _rotation_angle(R: FloatArray) -> FloatArray:
    """Angle (rad) of rotation matrices (N, 3, 3): ``atan2(|sin|, cos)`` from the skew part and
    the trace, accurate at small angles (where the trace's arccos is not); agrees with evo's
    rotation-vector norm to round-off."""
    s = 0.5 * np.stack(
        [R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1
    )
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    return np.asarray(np.arctan2(np.linalg.norm(s, axis=1), c), dtype=np.float64)


def _relation(E: FloatArray, relation: PoseRelation) -> FloatArray:
    if relation == "trans":
        return np.asarray(np.linalg.norm(E[:, :3, 3], axis=1), dtype=np.float64)
    if relation == "rot":
        return _rotation_angle(E[:, :3, :3])
    if relation == "full":
        return np.asarray(np.linalg.norm(E - np.eye(4), axis=(1, 2)), dtype=np.float64)
    raise EvalError(f"unknown pose relation {relation!r}; choose trans, rot or full")


def _inv_se3(T: FloatArray) -> FloatArray:
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def ape_matrices(ref: Trajectory, est: Trajectory) -> FloatArray:
    """Absolute error poses ``E_i = Q_i^-1 P_i`` (N, 4, 4) of matched trajectories."""
    if len(ref) != len(est):
        raise EvalError("APE needs matched trajectories of equal length; associate them first")
    return np.asarray(_inv_se3(ref.matrices()) @ est.matrices(), dtype=np.float64)


def pose_errors(E: FloatArray, relation: PoseRelation) -> FloatArray:
    """Per-pose error of error poses ``E`` (N, 4, 4): translation norm (m), rotation angle
    (rad) or ``|E - I|`` (full), as evo's pose relations."""
    return _relation(E, relation)


def ape(ref: Trajectory, est: Trajectory, relation: PoseRelation = "trans") -> FloatArray:
    """Absolute pose error per matched pose (metres, radians, or unitless for ``full``)."""
    if len(ref) != len(est):
        raise EvalError("APE needs matched trajectories of equal length; associate them first")
    if relation == "trans":
        return np.asarray(np.linalg.norm(ref.p_W_B - est.p_W_B, axis=1), dtype=np.float64)
    return _relation(ape_matrices(ref, est), relation)


def rpe_pairs(
    traj: Trajectory, delta: float, unit: RpeUnit, *, all_pairs: bool = False, rel_tol: float = 0.1
) -> tuple[IntArray, IntArray]:
    """Index pairs (i, j) a ``delta`` apart, by the rules of evo 1.38.1.

    Frames: consecutive pairs ``(0, d), (d, 2d), ...``; all pairs ``(i, i + d)``. Metres (the path
    travelled): consecutive pairs chain from the first pose, each ending where the path since the
    previous end first reaches ``delta``; all pairs take, for each start, the first end whose path
    is nearest ``delta``, kept when within ``rel_tol * delta``. Seconds (which evo lacks) work
    like metres on the time since the first pose.
    """
    n = len(traj)
    if delta <= 0:
        raise EvalError(f"the RPE delta must be > 0, got {delta}")
    if unit == "frames":
        step = round(delta)
        if step < 1 or abs(step - delta) > 1e-9:
            raise EvalError(f"an RPE delta in frames must be a whole number >= 1, got {delta}")
        if all_pairs:
            i = np.arange(max(n - step, 0))
            return i, i + step
        ids = np.arange(0, n, step)
        return ids[:-1], ids[1:]
    if unit == "metres":
        p = traj.p_W_B
        steps = np.linalg.norm(p[:-1] - p[1:], axis=1) if n > 1 else np.zeros(0)
        if not all_pairs:
            return _chain_pairs(steps.tolist(), delta)
        return _nearest_pairs(np.concatenate([[0.0], np.cumsum(steps)]), delta, rel_tol * delta)
    if unit == "seconds":
        if not traj.timed:
            raise EvalError("an RPE delta in seconds needs timestamps")
        # Integer nanoseconds, so 0.3 s steps are not lost to float round-off.
        delta_ns = s_to_ns(delta)
        if not all_pairs:
            return _chain_pairs(np.diff(traj.t_ns).tolist(), delta_ns)
        return _nearest_pairs(traj.t_ns - traj.t_ns[0], delta_ns, round(rel_tol * delta_ns))
    raise EvalError(f"unknown RPE unit {unit!r}; choose frames, seconds or metres")


def _chain_pairs(steps: list[float] | list[int], delta: float) -> tuple[IntArray, IntArray]:
    """Consecutive pairs from pose 0: a pose ends a pair when the sum of the steps since the
    previous end reaches ``delta`` (evo's ``filter_pairs_by_path``, same float sums)."""
    ids = [0]
    acc: float = 0
    for k, step in enumerate(steps, start=1):
        acc += step
        if acc >= delta:
            ids.append(k)
            acc = 0
    arr = np.array(ids, dtype=np.int64)
    return arr[:-1], arr[1:]


def _nearest_pairs(
    dist: FloatArray | IntArray, delta: float, tol: float
) -> tuple[IntArray, IntArray]:
    """For each start i < n - 1, the first j > i minimising ``|(dist[j] - dist[i]) - delta|``
    (evo's all-pairs ``argmin``, ties to the earlier pose), kept when within ``tol``."""
    n = len(dist)
    if n < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    i = np.arange(n - 1)
    j = np.searchsorted(dist, dist[i] + delta)
    # The optimum is next to the crossing; round-off can move it by one, so look at four.
    cand = np.clip(j[:, None] + np.arange(-2, 2), i[:, None] + 1, n - 1)
    # A standstill repeats a distance: its first pose (after i) is the one argmin finds.
    cand = np.maximum(np.searchsorted(dist, dist[cand], side="left"), i[:, None] + 1)
    err = np.abs((dist[cand] - dist[i][:, None]) - delta)
    best = np.lexsort((cand, err), axis=-1)[:, 0]  # least error, then earliest pose
    ok = err[i, best] <= tol
    return i[ok], cand[i, best][ok]


def _checked_pairs(
    ref: Trajectory,
    est: Trajectory,
    delta: float,
    unit: RpeUnit,
    all_pairs: bool,
    pairs_from: Literal["estimate", "reference"],
) -> tuple[IntArray, IntArray]:
    """:func:`rpe_pairs` on matched trajectories; an ``EvalError`` when they are not matched or
    no pair is ``delta`` apart."""
    if len(ref) != len(est):
        raise EvalError("RPE needs matched trajectories of equal length; associate them first")
    i, j = rpe_pairs(est if pairs_from == "estimate" else ref, delta, unit, all_pairs=all_pairs)
    if len(i) == 0:
        raise EvalError(
            f"RPE delta {delta} {unit} gives no pairs on a trajectory of {len(est)} poses"
        )
    return i, j


def rpe_matrices(
    ref: Trajectory,
    est: Trajectory,
    *,
    delta: float = 1.0,
    unit: RpeUnit = "frames",
    all_pairs: bool = False,
    pairs_from: Literal["estimate", "reference"] = "estimate",
) -> tuple[FloatArray, IntArray]:
    """Relative error poses ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` (M, 4, 4) over the pairs of
    :func:`rpe_pairs`, and each pair's end index ``j``."""
    i, j = _checked_pairs(ref, est, delta, unit, all_pairs, pairs_from)
    return _relative_errors(ref, est, i, j), j


def _matrices(traj: Trajectory, idx: IntArray) -> FloatArray:
    """``traj.matrices()[idx]``, built for those rows only."""
    T = np.zeros((len(idx), 4, 4))
    T[:, :3, :3] = Rotation.from_quat(traj.q_W_B_xyzw[idx]).as_matrix()
    T[:, :3, 3] = traj.p_W_B[idx]
    T[:, 3, 3] = 1.0
    return T


def _relative_errors(ref: Trajectory, est: Trajectory, i: IntArray, j: IntArray) -> FloatArray:
    """``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` (M, 4, 4) of the pairs (i, j)."""
    Q_rel = _inv_se3(_matrices(ref, i)) @ _matrices(ref, j)
    P_rel = _inv_se3(_matrices(est, i)) @ _matrices(est, j)
    return np.asarray(_inv_se3(Q_rel) @ P_rel, dtype=np.float64)


def rpe(
    ref: Trajectory,
    est: Trajectory,
    *,
    delta: float = 1.0,
    unit: RpeUnit = "frames",
    relation: PoseRelation = "trans",
    all_pairs: bool = False,
    pairs_from: Literal["estimate", "reference"] = "estimate",
) -> tuple[FloatArray, IntArray]:
    """Relative pose error per pair, and each pair's end index (for plotting against time).
    The pairs' error poses are made :data:`RPE_CHUNK` at a time: all pairs of a 30-minute run
    at once were ~1 kB a pose."""
    i, j = _checked_pairs(ref, est, delta, unit, all_pairs, pairs_from)
    out = np.empty(len(i))
    for s in range(0, len(i), RPE_CHUNK):
        c = slice(s, s + RPE_CHUNK)
        out[c] = _relation(_relative_errors(ref, est, i[c], j[c]), relation)
    return out, j


def _normalized_squared(e: FloatArray, cov: FloatArray, what: str) -> FloatArray:
    e = np.asarray(e, dtype=np.float64)
    cov = np.asarray(cov, dtype=np.float64)
    if e.ndim != 2 or cov.shape != (*e.shape, e.shape[1]):
        raise EvalError(
            f"{what} needs errors (N, n) and covariances (N, n, n), got {e.shape} and {cov.shape}"
        )
    try:
        sol = np.linalg.solve(cov, e[..., None])[..., 0]
    except np.linalg.LinAlgError:
        raise EvalError(f"{what}: a covariance is singular") from None
    return np.asarray(np.sum(e * sol, axis=1), dtype=np.float64)


def nees(err: FloatArray, P: FloatArray) -> FloatArray:
    """Normalised estimation error squared ``e^T P^-1 e`` per row: ``err`` (N, n), ``P`` (N, n, n)."""
    return _normalized_squared(err, P, "NEES")


def nis(innovation: FloatArray, S: FloatArray) -> FloatArray:
    """Normalised innovation squared ``y^T S^-1 y`` per row: ``innovation`` (N, m), ``S`` (N, m, m)."""
    return _normalized_squared(innovation, S, "NIS")


def position_nees(ref: Trajectory, est: Trajectory) -> FloatArray:
    """Position NEES of matched poses, over the axes whose variance is positive (planar runs
    carry no variance across the plane)."""
    if est.cov_p is None:
        raise EvalError(f"{est.name or 'the estimate'} carries no covariance: no NEES")
    diag = np.diagonal(est.cov_p, axis1=1, axis2=2)
    axes = np.flatnonzero(np.all(diag > 0, axis=0))
    if len(axes) == 0:
        raise EvalError("no axis has a positive variance: no NEES")
    e = (est.p_W_B - ref.p_W_B)[:, axes]
    return nees(e, est.cov_p[:, axes][:, :, axes])


def settling_time_s(t: FloatArray, err: FloatArray, band: float) -> float:
    """First time after which ``err`` stays below ``band`` (NaN if it never settles)."""
    outside = np.flatnonzero(~(err < band))
    if len(outside) == 0:
        return float(t[0])
    last = outside[-1]
    return float(t[last + 1]) if last + 1 < len(t) else math.nan
