"""Trajectories from PX4 ULog files, through ``pyulog``.

Reads a local position topic (``vehicle_local_position``, or its ``_groundtruth`` twin) and an
attitude topic (``vehicle_attitude``...), converts NED/FRD to ENU/FLU here at the boundary,
and slerps the attitude to the position samples' times. Times are ``timestamp_sample`` (the
time of validity) where the log fills it in, else ``timestamp``, in microseconds since boot.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from quadnav.errors import GeometryError, IoError
from quadnav.geometry.frames import ned_to_enu, rotation_ned_frd_to_enu_flu
from quadnav.geometry.trajectory import Trajectory

__all__ = ["read_ulog_trajectory"]


def _dataset(ulog: Any, name: str, path: Path) -> dict[str, np.ndarray]:
    for d in ulog.data_list:
        if d.name == name and d.multi_id == 0:
            return dict(d.data)
    have = sorted({d.name for d in ulog.data_list})
    raise IoError(f"{path}: no {name} topic in the log (has {len(have)} topics)")


def _times_us(data: dict[str, np.ndarray]) -> np.ndarray:
    sample = data.get("timestamp_sample")
    # Simulator ground-truth topics leave timestamp_sample at zero: fall back to timestamp.
    if sample is not None and np.all(np.asarray(sample) > 0):
        return np.asarray(sample, dtype=np.int64)
    return np.asarray(data["timestamp"], dtype=np.int64)


def read_ulog_trajectory(path: Path, *, groundtruth: bool = False) -> Trajectory:
    """PX4's own estimate (or the simulator's ground truth) from a ULog, in ENU/FLU."""
    from pyulog import ULog  # type: ignore[import-untyped]

    path = Path(path)
    if not path.is_file():
        raise IoError(f"ULog file not found: {path}")
    suffix = "_groundtruth" if groundtruth else ""
    pos_topic, att_topic = f"vehicle_local_position{suffix}", f"vehicle_attitude{suffix}"
    try:
        ulog = ULog(str(path), [pos_topic, att_topic])
    except Exception as exc:  # pyulog raises bare exceptions on corrupt files
        raise IoError(f"{path}: cannot parse the ULog: {exc}") from None
    pos = _dataset(ulog, pos_topic, path)
    att = _dataset(ulog, att_topic, path)
    t_pos = _times_us(pos) * 1000
    t_att = _times_us(att) * 1000
    p_ned = np.column_stack([pos["x"], pos["y"], pos["z"]]).astype(np.float64)
    q_wxyz = np.column_stack([att[f"q[{k}]"] for k in range(4)]).astype(np.float64)
    # Keep finite, strictly increasing samples (a log can repeat a stamp or hold NaN before init).
    keep_p = np.isfinite(p_ned).all(axis=1)
    keep_a = np.isfinite(q_wxyz).all(axis=1) & (np.linalg.norm(q_wxyz, axis=1) > 0.5)
    t_pos, p_ned = t_pos[keep_p], p_ned[keep_p]
    t_att, q_wxyz = t_att[keep_a], q_wxyz[keep_a]
    up = np.concatenate([[True], np.diff(t_pos) > 0])
    ua = np.concatenate([[True], np.diff(t_att) > 0])
    t_pos, p_ned, t_att, q_wxyz = t_pos[up], p_ned[up], t_att[ua], q_wxyz[ua]
    if len(t_att) < 2 or len(t_pos) < 1:
        raise IoError(f"{path}: too few valid {pos_topic}/{att_topic} samples")
    try:
        attitude = Trajectory(
            t_ns=t_att,
            p_W_B=np.zeros((len(t_att), 3)),
            q_W_B_xyzw=q_wxyz[:, [1, 2, 3, 0]],
            name="attitude",
        )
        inside = (t_pos >= t_att[0]) & (t_pos <= t_att[-1])
        if not inside.any():
            raise IoError(f"{path}: {pos_topic} and {att_topic} do not overlap in time")
        R_NED_FRD = attitude.interpolate(t_pos[inside]).R_W_B
        R_ENU_FLU = rotation_ned_frd_to_enu_flu(R_NED_FRD)
        return Trajectory(
            t_ns=t_pos[inside],
            p_W_B=ned_to_enu(p_ned[inside]),
            q_W_B_xyzw=R_ENU_FLU.as_quat(),
            name=f"{path.stem}_{pos_topic}",
        )
    except GeometryError as exc:
        raise IoError(f"{path}: {exc}") from None
