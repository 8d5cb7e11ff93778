"""PX4 ULog sensor streams and estimator settings, for replaying a flight through our EKF.

Reads what exists across PX4 versions: the IMU (``sensor_combined``, else ``vehicle_imu``
delta angles/velocities), GNSS (``vehicle_gps_position`` or ``sensor_gps``), barometer
(``vehicle_air_data``), magnetometer (``vehicle_magnetometer``), external vision
(``vehicle_visual_odometry``) and distance sensors, PX4's land detector, and the EKF2
parameters. NED/FRD become ENU/FLU here. What is missing or unusable is reported in
``notes``, never fatal unless there is no IMU at all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import IoError
from quadnav.geometry.frames import frd_to_flu, ned_to_enu
from quadnav.units import s_to_ns

__all__ = ["Px4Validity", "UlogSensors", "held_flags", "read_ulog_sensors"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

TOPICS = [
    "sensor_combined", "vehicle_imu", "vehicle_gps_position", "sensor_gps", "vehicle_air_data",
    "vehicle_magnetometer", "vehicle_visual_odometry", "distance_sensor", "vehicle_land_detected",
    "vehicle_local_position", "vehicle_attitude", "estimator_states", "estimator_innovations",
    "vehicle_local_position_groundtruth", "vehicle_attitude_groundtruth",
]  # fmt: skip


def held_flags(t_msg_ns: IntArray, flags: NDArray[Any], t_ns: IntArray) -> NDArray[np.bool_]:
    """A logged flag at each time of ``t_ns``, held from one message to the next (false
    before the first)."""
    t = np.asarray(t_ns, dtype=np.int64)
    if len(t_msg_ns) == 0:
        return np.zeros(len(t), bool)
    j = np.searchsorted(t_msg_ns, t, side="right") - 1
    held: NDArray[np.bool_] = (j >= 0) & np.asarray(flags, bool)[np.clip(j, 0, len(t_msg_ns) - 1)]
    return held


@dataclass(frozen=True, slots=True, kw_only=True)
class Px4Validity:
    """When PX4 itself called its estimate valid: ``vehicle_local_position``'s ``xy_valid`` and
    ``z_valid`` (each held until the next message) and the times of ``vehicle_attitude``."""

    t_ns: IntArray
    xy_valid: NDArray[np.bool_]
    z_valid: NDArray[np.bool_]
    att_t_ns: IntArray

    def at(
        self, t_ns: IntArray, *, att_max_gap_s: float = 0.5
    ) -> tuple[NDArray[np.bool_], NDArray[np.bool_], NDArray[np.bool_]]:
        """(xy valid, z valid, attitude present) at each time: the flags as last logged (false
        before the first message), an attitude sample within ``att_max_gap_s``."""
        t = np.asarray(t_ns, dtype=np.int64)
        xy = held_flags(self.t_ns, self.xy_valid, t)
        z = held_flags(self.t_ns, self.z_valid, t)
        att = np.zeros(len(t), bool)
        if len(self.att_t_ns):
            k = np.clip(np.searchsorted(self.att_t_ns, t), 1, len(self.att_t_ns) - 1)
            if len(self.att_t_ns) == 1:
                k = np.zeros(len(t), np.int64)
            gap = np.minimum(np.abs(self.att_t_ns[k] - t), np.abs(self.att_t_ns[k - 1] - t))
            att = gap <= s_to_ns(att_max_gap_s)
        return xy, z, att


@dataclass
class UlogSensors:
    """Sensor streams in ENU/FLU with times of validity in nanoseconds since boot."""

    path: Path
    duration_s: float
    imu_t_ns: IntArray
    gyro_rad_s: FloatArray  # (N, 3) FLU
    accel_m_s2: FloatArray  # (N, 3) FLU
    imu_clipping: (
        IntArray  # PX4's clipping bits per sample: accelerometer x, y, z (0-2), gyro (3-5)
    )
    gps: dict[str, NDArray[Any]] = field(default_factory=dict)
    baro: dict[str, NDArray[Any]] = field(default_factory=dict)
    mag: dict[str, NDArray[Any]] = field(default_factory=dict)
    landed: dict[str, NDArray[Any]] = field(default_factory=dict)
    vision: dict[str, NDArray[Any]] = field(default_factory=dict)
    range: dict[str, NDArray[Any]] = field(default_factory=dict)
    px4_innovations: dict[str, NDArray[Any]] = field(default_factory=dict)
    local_origin_lla: tuple[float, float, float] | None = None
    earth_field_declination_rad: float | None = None
    params: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    t_start_ns: int = 0  # the log's start (ULog header), the origin of every plot's time axis
    px4_validity: Px4Validity | None = None


def _data(ulog: Any, name: str) -> dict[str, NDArray[Any]] | None:
    for d in ulog.data_list:
        if d.name == name and d.multi_id == 0:
            return {k: np.asarray(v) for k, v in d.data.items()}
    return None


def _t_ns(d: dict[str, NDArray[Any]]) -> IntArray:
    ts = d.get("timestamp_sample")
    t = ts if ts is not None and np.all(ts > 0) else d["timestamp"]
    return np.asarray(t, dtype=np.int64) * 1000


def _vec(d: dict[str, NDArray[Any]], fmt: str) -> FloatArray:
    return np.column_stack([d[fmt.format(k)] for k in range(3)]).astype(np.float64)


def _px4_validity(
    lp: dict[str, NDArray[Any]] | None, att: dict[str, NDArray[Any]] | None
) -> Px4Validity | None:
    if lp is None and att is None:
        return None
    empty = np.zeros(0, np.int64)
    t = np.asarray(lp["timestamp"], np.int64) * 1000 if lp is not None else empty
    ones = np.ones(len(t), bool)
    xy = np.asarray(lp["xy_valid"]) > 0 if lp is not None and "xy_valid" in lp else ones
    z = np.asarray(lp["z_valid"]) > 0 if lp is not None and "z_valid" in lp else ones
    t_att = np.asarray(att["timestamp"], np.int64) * 1000 if att is not None else empty
    return Px4Validity(t_ns=t, xy_valid=xy, z_valid=z, att_t_ns=np.sort(t_att))


def _imu(
    ulog: Any, path: Path, notes: list[str]
) -> tuple[IntArray, FloatArray, FloatArray, IntArray]:
    """Times, rates, specific forces (FLU) and PX4's clipping bits of the IMU."""
    sc = _data(ulog, "sensor_combined")
    if sc is not None:
        t = np.asarray(sc["timestamp"], dtype=np.int64) * 1000
        gyro = frd_to_flu(_vec(sc, "gyro_rad[{}]"))
        accel = frd_to_flu(_vec(sc, "accelerometer_m_s2[{}]"))
        # PX4's per-axis bits (x, y, z: FRD and FLU share the axes): accelerometer in bits
        # 0-2, gyro in bits 3-5
        clip = np.zeros(len(t), dtype=np.int64)
        for key, shift in (("accelerometer_clipping", 0), ("gyro_clipping", 3)):
            if key in sc:
                clip |= (np.asarray(sc[key]).astype(np.int64) & 7) << shift
    else:
        vi = _data(ulog, "vehicle_imu")
        if vi is None:
            raise IoError(f"{path}: no IMU in the log (neither sensor_combined nor vehicle_imu)")
        notes.append("IMU from vehicle_imu (delta angles / velocities)")
        t = _t_ns(vi)
        dt_a = np.asarray(vi["delta_velocity_dt"], dtype=np.float64) * 1e-6
        dt_g = np.asarray(vi["delta_angle_dt"], dtype=np.float64) * 1e-6
        with np.errstate(divide="ignore", invalid="ignore"):
            gyro = frd_to_flu(_vec(vi, "delta_angle[{}]") / dt_g[:, None])
            accel = frd_to_flu(_vec(vi, "delta_velocity[{}]") / dt_a[:, None])
        clip = np.asarray(vi.get("delta_velocity_clipping", np.zeros(len(t))), dtype=np.int64) & 7
    return t, gyro, accel, clip


def _gps(g: dict[str, NDArray[Any]]) -> dict[str, NDArray[Any]]:
    """A GNSS topic's fixes (either PX4 naming), velocities in ENU."""
    lat = g["latitude_deg"] if "latitude_deg" in g else g["lat"] * 1e-7
    lon = g["longitude_deg"] if "longitude_deg" in g else g["lon"] * 1e-7
    alt = g["altitude_ellipsoid_m"] if "altitude_ellipsoid_m" in g else g["alt_ellipsoid"] * 1e-3
    v_ned = np.column_stack([g["vel_n_m_s"], g["vel_e_m_s"], g["vel_d_m_s"]])
    gps = {"t_ns": _t_ns(g), "lat": np.asarray(lat, float), "lon": np.asarray(lon, float),
           "alt": np.asarray(alt, float), "v_enu": ned_to_enu(v_ned), "eph": np.asarray(g["eph"], float),
           "epv": np.asarray(g["epv"], float), "s_var": np.asarray(g["s_variance_m_s"], float),
           "fix": np.asarray(g["fix_type"], np.int64)}  # fmt: skip
    if "satellites_used" in g:
        gps["nsats"] = np.asarray(g["satellites_used"], np.int64)
    if "hdop" in g and "vdop" in g:  # PX4's EKF2 takes PDOP as the norm of the two
        gps["pdop"] = np.hypot(np.asarray(g["hdop"], float), np.asarray(g["vdop"], float))
    return gps


def _vision(vo: dict[str, NDArray[Any]]) -> dict[str, NDArray[Any]]:
    """External-vision poses (ENU/FLU) with their variances and reset counters ({} if unusable)."""
    pos_key = "position[{}]" if "position[0]" in vo else None
    if pos_key is None and "x" in vo:
        p_ned = np.column_stack([vo["x"], vo["y"], vo["z"]])
    elif pos_key is not None:
        p_ned = _vec(vo, pos_key)
    else:
        p_ned = None
    if p_ned is not None and "q[0]" in vo:
        from scipy.spatial.transform import Rotation

        from quadnav.geometry.frames import rotation_ned_frd_to_enu_flu

        q_wxyz = np.column_stack([vo[f"q[{k}]"] for k in range(4)]).astype(np.float64)
        good = (
            np.isfinite(q_wxyz).all(axis=1)
            & (np.linalg.norm(q_wxyz, axis=1) > 0.5)
            & np.isfinite(p_ned).all(axis=1)
        )
        R = rotation_ned_frd_to_enu_flu(Rotation.from_quat(q_wxyz[good][:, [1, 2, 3, 0]]))
        var = (
            _vec(vo, "position_variance[{}]")[good]
            if "position_variance[0]" in vo
            else np.full((int(good.sum()), 3), np.nan)
        )
        return {"t_ns": _t_ns(vo)[good], "p": ned_to_enu(p_ned[good]), "q_xyzw": R.as_quat(),
                "var": var, "reset": np.asarray(vo.get("reset_counter", np.zeros(len(good))))[good].astype(np.int64)}  # fmt: skip
    return {}


def _px4_state(ulog: Any, out: UlogSensors, params: dict[str, float]) -> None:
    """What PX4 itself logged: its validity flags, local origin, earth field and innovations."""
    lp = _data(ulog, "vehicle_local_position")
    out.px4_validity = _px4_validity(lp, _data(ulog, "vehicle_attitude"))
    if lp is not None and "ref_lat" in lp:
        ok = (
            np.flatnonzero(np.asarray(lp["xy_valid"]) > 0)
            if "xy_valid" in lp
            else np.arange(len(lp["ref_lat"]))
        )
        if len(ok):
            k = int(ok[-1])
            out.local_origin_lla = (
                float(lp["ref_lat"][k]),
                float(lp["ref_lon"][k]),
                float(lp["ref_alt"][k]),
            )
    es = _data(ulog, "estimator_states")
    if es is not None and "states[16]" in es:
        # PX4's earth field states (NED, gauss): the declination its world magnetic model gave
        n, e = float(np.median(es["states[16]"][-50:])), float(np.median(es["states[17]"][-50:]))
        if math.hypot(n, e) > 1e-3:
            out.earth_field_declination_rad = math.atan2(e, n)
    if out.earth_field_declination_rad is None and "EKF2_MAG_DECL" in params:
        out.earth_field_declination_rad = math.radians(params["EKF2_MAG_DECL"])
    inn = _data(ulog, "estimator_innovations")
    if inn is not None:
        keep = {
            k: v
            for k, v in inn.items()
            if k.startswith(("gps_hpos", "gps_vpos", "baro_vpos", "heading", "mag_field"))
        }
        out.px4_innovations = {"t_ns": np.asarray(inn["timestamp"], np.int64) * 1000, **keep}


def read_ulog_sensors(path: Path) -> UlogSensors:
    from pyulog import ULog  # type: ignore[import-untyped]

    path = Path(path)
    if not path.is_file():
        raise IoError(f"ULog file not found: {path}")
    try:
        ulog = ULog(str(path), TOPICS)
    except Exception as exc:  # pyulog raises bare exceptions on corrupt or truncated files
        raise IoError(f"{path}: cannot parse the ULog: {exc}") from None
    notes: list[str] = []
    params = {k: float(v) for k, v in ulog.initial_parameters.items() if k.startswith("EKF2_")}
    duration = (ulog.last_timestamp - ulog.start_timestamp) * 1e-6
    t, gyro, accel, clip = _imu(ulog, path, notes)
    out = UlogSensors(
        path,
        duration,
        t,
        np.asarray(gyro, float),
        np.asarray(accel, float),
        clip,
        params=params,
        notes=notes,
        t_start_ns=int(ulog.start_timestamp) * 1000,
    )
    g = _data(ulog, "vehicle_gps_position") or _data(ulog, "sensor_gps")
    if g is not None:
        out.gps = _gps(g)
    else:
        notes.append("no GNSS topic: replaying without GNSS")
    b = _data(ulog, "vehicle_air_data")
    if b is not None:
        out.baro = {"t_ns": _t_ns(b), "alt": np.asarray(b["baro_alt_meter"], float)}
    else:
        notes.append("no vehicle_air_data: replaying without barometer")
    m = _data(ulog, "vehicle_magnetometer")
    if m is not None:
        out.mag = {"t_ns": _t_ns(m), "field_B": frd_to_flu(_vec(m, "magnetometer_ga[{}]"))}
    else:
        notes.append("no vehicle_magnetometer: replaying without magnetometer")
    vo = _data(ulog, "vehicle_visual_odometry")
    if vo is not None:
        out.vision = _vision(vo)
    ds = _data(ulog, "distance_sensor")
    if ds is not None and "current_distance" in ds:
        down = np.asarray(ds.get("orientation", np.full(len(ds["current_distance"]), 25))) == 25
        out.range = {"t_ns": _t_ns(ds)[down], "range_m": np.asarray(ds["current_distance"], float)[down],
                     "min_m": np.asarray(ds["min_distance"], float)[down], "max_m": np.asarray(ds["max_distance"], float)[down]}  # fmt: skip
    ld = _data(ulog, "vehicle_land_detected")
    if ld is not None:
        out.landed = {
            "t_ns": np.asarray(ld["timestamp"], np.int64) * 1000,
            "landed": np.asarray(ld["landed"], bool),
        }
    _px4_state(ulog, out, params)
    return out
