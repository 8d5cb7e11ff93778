"""Comparing a replayed estimate with PX4's own and with SITL ground truth, honestly.

PX4 says when its estimate is good: ``vehicle_local_position.xy_valid`` / ``z_valid`` and the
presence of ``vehicle_attitude``. Each quantity is compared only where PX4 called its estimate
valid (horizontal where ``xy_valid``, vertical where ``z_valid``, attitude where an attitude
was logged), and the result says which spans were compared and which not, in seconds from the
log's start. Attitude is split into tilt (the angle between the two body up axes) and yaw.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.eval.associate import associate
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.ulog_sensors import Px4Validity

__all__ = ["Comparison", "InnovationPair", "compare", "px4_innovations_as_ours", "spans_s"]

FloatArray = NDArray[np.float64]
Span = tuple[float, float]


@dataclass(frozen=True, slots=True, kw_only=True)
class Comparison:
    """Differences of an estimate from a reference over the spans PX4 called valid. Each
    ``*_spans_s`` lists the compared (start, end) spans in seconds from the log's start;
    ``not_compared_s`` the (quantity, start, end) spans of the estimate that were left out,
    those of some duration (a single sample left out is counted in ``n_*``, not listed)."""

    n: int
    n_horizontal: int
    n_vertical: int
    n_attitude: int
    horizontal_rms_m: float
    horizontal_max_m: float
    vertical_rms_m: float
    vertical_max_m: float
    position_rms_m: float
    attitude_rms_deg: float
    tilt_rms_deg: float
    yaw_rms_deg: float
    t_of_max_vertical_s: float
    horizontal_spans_s: tuple[Span, ...]
    vertical_spans_s: tuple[Span, ...]
    attitude_spans_s: tuple[Span, ...]
    not_compared_s: tuple[tuple[str, float, float], ...]


def spans_s(t_ns: NDArray[np.int64], mask: NDArray[np.bool_], t0_ns: int) -> tuple[Span, ...]:
    """The runs of ``mask`` over the times ``t_ns`` as (first, last) seconds from ``t0_ns``."""
    m = np.asarray(mask, bool)
    if not m.any():
        return ()
    edges = np.flatnonzero(np.diff(np.concatenate([[0], m.astype(np.int8), [0]])))
    return tuple(
        (round((int(t_ns[a]) - t0_ns) * 1e-9, 3), round((int(t_ns[b - 1]) - t0_ns) * 1e-9, 3))
        for a, b in zip(edges[0::2], edges[1::2], strict=True)
    )


def _rms(x: FloatArray) -> float:
    return float(np.sqrt(np.mean(x**2))) if len(x) else math.nan


def _max(x: FloatArray) -> float:
    return float(np.max(np.abs(x))) if len(x) else math.nan


def _tilt_yaw_deg(R_ref: FloatArray, R_est: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Tilt: the angle between the body up axes; yaw: the heading difference (wrapped)."""
    cos_tilt = np.clip(np.einsum("ni,ni->n", R_ref[:, :, 2], R_est[:, :, 2]), -1.0, 1.0)
    yaw_r = np.arctan2(R_ref[:, 1, 0], R_ref[:, 0, 0])
    yaw_e = np.arctan2(R_est[:, 1, 0], R_est[:, 0, 0])
    d_yaw = np.angle(np.exp(1j * (yaw_e - yaw_r)))
    return np.degrees(np.arccos(cos_tilt)), np.degrees(d_yaw)


def compare(
    ref: Trajectory, est: Trajectory, *, t0_ns: int, validity: Px4Validity | None
) -> Comparison:
    """``est`` against ``ref`` interpolated at ``est``'s times (within 0.5 s of a reference
    sample), each quantity where ``validity`` (PX4's own flags; None: everywhere) allows."""
    r, e = associate(ref, est, t_max_diff_s=0.5, interpolate=True)
    t = e.t_ns
    ones = np.ones(len(t), bool)
    xy, z, att = validity.at(t) if validity is not None else (ones, ones, ones)
    d = e.p_W_B - r.p_W_B
    h = np.linalg.norm(d[:, 0:2], axis=1)
    R_r, R_e = r.R_W_B.as_matrix(), e.R_W_B.as_matrix()
    rot = np.degrees((r.R_W_B.inv() * e.R_W_B).magnitude())
    tilt, yaw = _tilt_yaw_deg(R_r, R_e)
    dz = d[z, 2]
    paired = np.isin(est.t_ns, t)
    not_compared: list[tuple[str, float, float]] = []
    for name, mask in (("horizontal", xy), ("vertical", z), ("attitude", att)):
        full = np.zeros(len(est.t_ns), bool)
        full[np.flatnonzero(paired)] = mask
        # a single sample left out (a flag that flickers for one message, the estimate's last
        # sample past the reference's end) is a span of no duration: not a span
        not_compared += [(name, a, b) for a, b in spans_s(est.t_ns, ~full, t0_ns) if b > a]
    return Comparison(
        n=len(t),
        n_horizontal=int(xy.sum()),
        n_vertical=int(z.sum()),
        n_attitude=int(att.sum()),
        horizontal_rms_m=_rms(h[xy]),
        horizontal_max_m=_max(h[xy]),
        vertical_rms_m=_rms(dz),
        vertical_max_m=_max(dz),
        position_rms_m=_rms(np.linalg.norm(d[xy & z], axis=1)),
        attitude_rms_deg=_rms(rot[att]),
        tilt_rms_deg=_rms(tilt[att]),
        yaw_rms_deg=_rms(yaw[att]),
        t_of_max_vertical_s=float((t[z][int(np.argmax(np.abs(dz)))] - t0_ns) * 1e-9)
        if len(dz)
        else math.nan,
        horizontal_spans_s=spans_s(t, xy, t0_ns),
        vertical_spans_s=spans_s(t, z, t0_ns),
        attitude_spans_s=spans_s(t, att, t0_ns),
        not_compared_s=tuple(not_compared),
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class InnovationPair:
    """One innovation component of ours (``source``, column ``column`` of the fusion log) and
    PX4's same component in our convention (``px4_t_s`` seconds from the log's start)."""

    label: str
    source: str
    column: int
    px4_t_s: FloatArray
    px4_m: FloatArray


# (label, our source, our column, PX4's key, sign): PX4 logs NED innovations as the prediction
# minus the measurement; ours are ENU, the measurement minus the prediction. North and east
# change sign (and swap places); PX4's down-positive height innovation already equals ours.
_INNOVATIONS = (
    ("GNSS east innovation (m)", "gps", 0, "gps_hpos[1]", -1.0),
    ("GNSS north innovation (m)", "gps", 1, "gps_hpos[0]", -1.0),
    ("barometer height innovation (m)", "baro", 0, "baro_vpos", 1.0),
)


def px4_innovations_as_ours(
    px4: dict[str, NDArray[np.float64]], validity: Px4Validity | None, t0_ns: int
) -> tuple[InnovationPair, ...]:
    """PX4's logged innovations (``estimator_innovations``) in our convention, component by
    component, where PX4's estimate was valid (before, its innovations mean nothing)."""
    out = []
    for label, src, col, key, sign in _INNOVATIONS:
        if key not in px4 or "t_ns" not in px4:
            continue
        t = np.asarray(px4["t_ns"], dtype=np.int64)
        ok = np.ones(len(t), bool)
        if validity is not None:
            xy, z, _ = validity.at(t)
            ok = xy if src == "gps" else z
        v = sign * np.asarray(px4[key], dtype=np.float64)
        out.append(
            InnovationPair(
                label=label,
                source=src,
                column=col,
                px4_t_s=((t[ok] - t0_ns) * 1e-9).astype(np.float64),
                px4_m=v[ok],
            )
        )
    return tuple(out)
