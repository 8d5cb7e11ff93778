"""Error metrics: APE, RPE (frames, seconds or metres), their statistics, NEES and NIS.

APE and RPE follow the definitions evo uses, so results agree with it: APE compares matched
poses after alignment; RPE compares relative motions ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)``
(Q reference, P estimate) over pairs of poses a step apart.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import EvalError
from quadnav.geometry.trajectory import Trajectory

__all__ = [
    "PoseRelation",
    "RpeUnit",
    "ape",
    "error_stats",
    "nees",
    "nis",
    "position_nees",
    "rpe",
    "rpe_pairs",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
PoseRelation = Literal["trans", "rot", "full"]
RpeUnit = Literal["frames", "seconds", "metres"]


def error_stats(errors: FloatArray) -> dict[str, float]:
    """rmse, mean, median, std, min, max and sse of an error array (as evo reports them)."""
    e = np.asarray(errors, dtype=np.float64)
    if e.ndim != 1 or len(e) == 0:
        raise EvalError("statistics need a non-empty 1-D error array")
    return {
        "rmse": float(np.sqrt(np.mean(e**2))),
        "mean": float(np.mean(e)),
        "median": float(np.median(e)),
        "std": float(np.std(e)),
        "min": float(np.min(e)),
        "max": float(np.max(e)),
        "sse": float(np.sum(e**2)),
    }


def _rotation_angle(R: FloatArray) -> FloatArray:
    """Angle (rad) of rotation matrices (..., 3, 3), from the trace, clipped for round-off."""
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.asarray(np.arccos(np.clip(c, -1.0, 1.0)), dtype=np.float64)


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


def ape(ref: Trajectory, est: Trajectory, relation: PoseRelation = "trans") -> FloatArray:
    """Absolute pose error per matched pose (metres, radians, or unitless for ``full``)."""
    if len(ref) != len(est):
        raise EvalError("APE needs matched trajectories of equal length; associate them first")
    if relation == "trans":
        return np.asarray(np.linalg.norm(ref.p_W_B - est.p_W_B, axis=1), dtype=np.float64)
    E = np.einsum("nij,njk->nik", _inv_se3(ref.matrices()), est.matrices())
    return _relation(E, relation)


def rpe_pairs(
    traj: Trajectory, delta: float, unit: RpeUnit, *, all_pairs: bool = False, rel_tol: float = 0.1
) -> tuple[IntArray, IntArray]:
    """Index pairs (i, j) a ``delta`` apart (evo's rules).

    Consecutive pairs chain from each pair's end to the next; with ``all_pairs`` every pose
    starts a pair. In metres the distance is the path travelled; all-pairs accepts a pair
    whose path is within ``rel_tol * delta`` of ``delta``.
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
    dist: NDArray[np.float64] | NDArray[np.int64]
    if unit == "metres":
        steps = np.linalg.norm(np.diff(traj.p_W_B, axis=0), axis=1) if n > 1 else np.zeros(0)
        dist = np.concatenate([[0.0], np.cumsum(steps)])
    elif unit == "seconds":
        if not traj.timed:
            raise EvalError("an RPE delta in seconds needs timestamps")
        # Integer nanoseconds, so 0.3 s steps are not lost to float round-off.
        dist = traj.t_ns - traj.t_ns[0]
        delta = round(delta * 1e9)
    else:
        raise EvalError(f"unknown RPE unit {unit!r}; choose frames, seconds or metres")
    if all_pairs:
        tol = rel_tol * delta
        i = np.arange(n)
        j = np.searchsorted(dist, dist + delta)  # first index at or beyond delta
        j_lo = np.clip(j - 1, 0, n - 1)
        j_hi = np.clip(j, 0, n - 1)
        pick = np.where(
            np.abs(dist[j_hi] - dist - delta) <= np.abs(dist[j_lo] - dist - delta), j_hi, j_lo
        )
        ok = (pick > i) & (np.abs(dist[pick] - dist - delta) <= tol)
        return i[ok], pick[ok]
    chain: list[int] = []
    start = dist[0]
    k = 0
    # Consecutive: the first index whose distance from the previous id (or the start) reaches delta.
    while True:
        k = int(np.searchsorted(dist, start + delta, side="left"))
        while k < n and dist[k] - start < delta:
            k += 1
        if k >= n:
            break
        chain.append(k)
        start = dist[k]
    arr = np.array(chain, dtype=np.int64)
    return arr[:-1], arr[1:]


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
    """Relative pose error per pair, and each pair's end index (for plotting against time)."""
    if len(ref) != len(est):
        raise EvalError("RPE needs matched trajectories of equal length; associate them first")
    i, j = rpe_pairs(est if pairs_from == "estimate" else ref, delta, unit, all_pairs=all_pairs)
    if len(i) == 0:
        raise EvalError(
            f"RPE delta {delta} {unit} gives no pairs on a trajectory of {len(est)} poses"
        )
    Q, P = ref.matrices(), est.matrices()
    Q_rel = np.einsum("nij,njk->nik", _inv_se3(Q[i]), Q[j])
    P_rel = np.einsum("nij,njk->nik", _inv_se3(P[i]), P[j])
    E = np.einsum("nij,njk->nik", _inv_se3(Q_rel), P_rel)
    return _relation(E, relation), j


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
