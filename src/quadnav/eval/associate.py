"""Pairing an estimate with its reference by timestamp (nearest neighbour or interpolation)."""

from __future__ import annotations

import math

import numpy as np

from quadnav.errors import EvalError
from quadnav.geometry.trajectory import Trajectory
from quadnav.units import s_to_ns

__all__ = ["associate"]

_INT64_MIN, _INT64_MAX = -(2**63), 2**63 - 1


def _span(t: Trajectory) -> str:
    return f"[{t.t_ns[0] * 1e-9:.3f}, {t.t_ns[-1] * 1e-9:.3f}] s"


def associate(
    ref: Trajectory,
    est: Trajectory,
    *,
    t_max_diff_s: float = 0.01,
    t_offset_s: float = 0.0,
    interpolate: bool = False,
) -> tuple[Trajectory, Trajectory]:
    """Matched (reference, estimate) of equal length, in the estimate's time order.

    The estimate's times are shifted by ``t_offset_s`` first (and stay shifted in the result). Nearest neighbour: each estimate
    pose takes the closest reference pose within ``t_max_diff_s``, each reference pose used
    once (the closest claim wins). Interpolation: the reference is interpolated (linear
    position, slerp attitude) at each estimate time inside its span whose nearest reference
    sample is within ``t_max_diff_s``. Trajectories without timestamps (KITTI) pair by index.
    """
    if not 0 <= t_max_diff_s < 9e9:  # also NaN; 9e9 s is the range of int64 nanoseconds
        raise EvalError(f"--t-max-diff must be finite and >= 0 s, got {t_max_diff_s}")
    if len(ref) == 0 or len(est) == 0:
        raise EvalError("cannot associate an empty trajectory")
    if not ref.timed or not est.timed:
        if ref.timed != est.timed:
            raise EvalError(
                "one trajectory has timestamps and the other has none (KITTI?): cannot pair them"
            )
        if len(ref) != len(est):
            raise EvalError(
                f"trajectories without timestamps pair by index but have {len(ref)} and {len(est)} poses"
            )
        return ref, est
    offset_ns = s_to_ns(t_offset_s) if math.isfinite(t_offset_s) else None
    if offset_ns is None or not (
        int(est.t_ns[0]) + offset_ns >= _INT64_MIN and int(est.t_ns[-1]) + offset_ns <= _INT64_MAX
    ):
        raise EvalError(
            f"--t-offset {t_offset_s} s moves the estimate's timestamps out of range "
            "(signed 64-bit nanoseconds)"
        )
    shifted = est.shifted(offset_ns) if offset_ns else est  # no copy of a long estimate
    t_e = shifted.t_ns
    t_r = ref.t_ns
    max_diff = s_to_ns(t_max_diff_s)
    k = (
        np.clip(np.searchsorted(t_r, t_e), 1, len(t_r) - 1)
        if len(t_r) > 1
        else np.zeros(len(t_e), int)
    )
    left = np.maximum(k - 1, 0)
    d_left = np.abs(t_e - t_r[left])
    d_right = np.abs(t_r[k] - t_e)
    nearest = np.where(d_right < d_left, k, left)
    d = np.minimum(d_left, d_right)
    ok = d <= max_diff
    if interpolate:
        ok &= (t_e >= t_r[0]) & (t_e <= t_r[-1])
        idx_e = np.flatnonzero(ok)
        if len(idx_e) == 0:
            raise _no_overlap(ref, est, t_max_diff_s)
        matched = shifted if len(idx_e) == len(shifted) else shifted.select(idx_e)
        return ref.interpolate(t_e[idx_e]), matched
    idx_e = np.flatnonzero(ok)
    if len(idx_e) == 0:
        raise _no_overlap(ref, est, t_max_diff_s)
    idx_r = nearest[idx_e]
    # One reference pose per estimate pose: where several claim it, the closest keeps it.
    order = np.lexsort((d[idx_e], idx_r))
    first = np.concatenate([[True], np.diff(idx_r[order]) != 0])
    keep = np.sort(order[first])
    return ref.select(idx_r[keep]), shifted.select(idx_e[keep])


def _no_overlap(ref: Trajectory, est: Trajectory, t_max_diff_s: float) -> EvalError:
    return EvalError(
        f"no pose of {est.name or 'the estimate'} {_span(est)} lies within {t_max_diff_s} s of "
        f"{ref.name or 'the reference'} {_span(ref)}: no overlapping time (try --t-offset or --t-max-diff)"
    )
