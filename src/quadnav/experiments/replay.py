"""Replay a PX4 flight log through the navigation EKF (thesis 000 section 3.4.2: studying the
estimator offline on PX4's own log replay).

The sensor streams of :func:`quadnav.io.ulog_sensors.read_ulog_sensors` are merged in arrival
order, each measurement stamped with its time of validity (the log's sample time minus PX4's
configured delay for that sensor, as EKF2 does). The filter is aligned on the ground from the
first second of IMU data and the magnetometer, starts from PX4's EKF2 tuning read from the log,
and fuses zero velocity while PX4's land detector says landed.
"""

from __future__ import annotations

import heapq
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, ValidationError

from quadnav.config_model import MAX_DELAY_S, MIN_SIGMA, ConfigModel
from quadnav.errors import ExperimentError
from quadnav.estimation.gnss_checks import CHECK_NAMES, GnssCheckConfig, GnssChecks, run_gnss_checks
from quadnav.estimation.horizon import (
    DelayedHorizonEstimator,
    HorizonConfig,
    SourceFusion,
    SourceStats,
    fusion_arrays,
)
from quadnav.estimation.imu_clipping import BADACC_NOISE_M_S2, ClippedImuSample
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig
from quadnav.estimation.nav_filter import (
    ImuCounts,
    InitialSigmas,
    NavFilterSetup,
    build_nav_filter,
    counts_json,
    ground_alignment,
)
from quadnav.geometry.navsat import GeoDatum, NavSatTransform
from quadnav.geometry.rotations import quat_xyzw_from_matrix
from quadnav.io.ulog_sensors import UlogSensors, held_flags
from quadnav.messages import (
    GpsSample,
    HeightSample,
    ImuSample,
    MagSample,
    PoseSample,
    RangeSample,
    Sample,
    VelocitySample,
)
from quadnav.units import s_to_ns

__all__ = [
    "CHECK_NAMES",
    "ReplayConfig",
    "ReplayResult",
    "config_from_px4",
    "gnss_checks_for",
    "replay",
]

FloatArray = NDArray[np.float64]


class ReplayConfig(ConfigModel):
    """The filter's settings for a replay; :func:`config_from_px4` fills them from EKF2's."""

    gyro_noise_rad_s: float = Field(0.015, gt=0)
    accel_noise_m_s2: float = Field(0.35, gt=0)
    gyro_bias_noise_rad_s2: float = Field(0.001, gt=0)
    accel_bias_noise_m_s3: float = Field(0.003, gt=0)
    gps_delay_s: float = Field(0.11, ge=0, le=MAX_DELAY_S)
    baro_delay_s: float = Field(0.0, ge=0, le=MAX_DELAY_S)
    mag_delay_s: float = Field(0.0, ge=0, le=MAX_DELAY_S)
    ev_delay_s: float = Field(0.0, ge=0, le=MAX_DELAY_S)
    range_delay_s: float = Field(0.005, ge=0, le=MAX_DELAY_S)
    ev_pos_noise_m: float = Field(0.1, gt=0)
    ev_yaw_noise_rad: float = Field(0.1, gt=0)
    range_noise_m: float = Field(0.1, gt=0)
    gps_pos_noise_m: float = Field(0.5, gt=0)
    gps_vel_noise_m_s: float = Field(0.3, gt=0)
    baro_noise_m: float = Field(3.5, gt=0)
    baro_bias_nsd_m_s: float | None = Field(
        0.13,
        gt=0,
        description="barometer bias random walk (PX4's baro_bias_nsd); null: no bias state",
    )
    heading_noise_rad: float = Field(0.3, gt=0)
    gate_sigma: float = Field(
        5.0, gt=0, description="innovation gate in standard deviations (EKF2_GPS_P_GATE); any > 0"
    )
    mag_declination_rad: float | None = Field(None, description="None: from the log")
    align_s: float = Field(1.0, gt=0)
    zero_velocity_when_landed: bool = True
    zero_velocity_sigma_m_s: float = Field(0.05, gt=0, description="standing still, within this")
    tau_vel_s: float = Field(0.25, gt=0)
    tau_pos_s: float = Field(0.25, gt=0)
    init_tilt_sigma_rad: float = Field(0.05, ge=MIN_SIGMA, description="P0: roll and pitch")
    init_yaw_sigma_rad: float = Field(0.3, ge=MIN_SIGMA, description="P0: heading")
    init_vel_sigma_m_s: float = Field(0.3, ge=MIN_SIGMA, description="P0: velocity")
    init_pos_sigma_m: float = Field(0.5, ge=MIN_SIGMA, description="P0: horizontal position")
    init_pos_sigma_gps_m: float = Field(
        2.0, ge=MIN_SIGMA, description="P0: horizontal position levelled from a GNSS fix"
    )
    init_height_sigma_m: float = Field(0.5, ge=MIN_SIGMA, description="P0: height")
    init_height_sigma_anchored_m: float = Field(
        0.01, ge=MIN_SIGMA, description="P0: height, with a barometer bias and no GNSS height"
    )
    init_gyro_bias_sigma_rad_s: float = Field(0.01, ge=MIN_SIGMA, description="P0: gyro bias")
    init_accel_bias_sigma_m_s2: float = Field(0.2, ge=MIN_SIGMA, description="P0: accel bias")
    min_gps_fix: int = Field(3, ge=2)
    gps_max_eph_m: float = Field(
        3.0, gt=0, description="fixes less precise than this are not used (EKF2_REQ_EPH)"
    )
    clipped_accel_noise_m_s2: float = Field(
        BADACC_NOISE_M_S2,
        gt=0,
        description="process noise of a clipped accelerometer axis (PX4's BADACC_BIAS_PNOISE)",
    )
    accel_bias_learn_gyro_limit_rad_s: float | None = Field(
        3.0,
        gt=0,
        description="no accelerometer-bias learning above this body rate (EKF2_ABL_GYRLIM); null: always",
    )
    accel_bias_learn_accel_limit_m_s2: float = Field(
        25.0, gt=0, description="nor above this specific force (EKF2_ABL_ACCLIM)"
    )
    accel_bias_learn_tau_s: float = Field(
        0.5, gt=0, description="decay of those peak detectors (EKF2_ABL_TAU)"
    )
    relevel_at_rest_s: float | None = Field(
        0.2,
        gt=0,
        description="after accelerometer clipping, re-level once the IMU shows rest this long; null: never",
    )
    gps_check_mask: int = Field(
        245, ge=0, description="PX4's GNSS checks to apply (EKF2_GPS_CHECK bits)"
    )
    gps_min_sats: int = Field(6, ge=0, description="EKF2_REQ_NSATS")
    gps_max_pdop: float = Field(2.5, gt=0, description="EKF2_REQ_PDOP")
    gps_max_epv_m: float = Field(5.0, gt=0, description="EKF2_REQ_EPV")
    gps_max_sacc_m_s: float = Field(0.5, gt=0, description="EKF2_REQ_SACC")
    gps_max_hdrift_m_s: float = Field(0.1, gt=0, description="EKF2_REQ_HDRIFT (landed, at rest)")
    gps_max_vdrift_m_s: float = Field(0.2, gt=0, description="EKF2_REQ_VDRIFT (landed, at rest)")
    gps_pass_s: float = Field(
        10.0, ge=0, description="the checks pass this long before GNSS is used (EKF2_REQ_GPS_H)"
    )
    gps_height: bool = Field(
        True,
        description="fuse the GNSS altitude (PX4: EKF2_GPS_CTRL bit 1, or EKF2_HGT_MODE=1 before v1.14)",
    )
    imu_downsample: int = Field(
        2,
        ge=1,
        le=10,
        description="average this many IMU samples into one filter step (PX4's EKF2 predicts at 100 Hz, EKF2_PREDICT_US)",
    )


def config_from_px4(
    params: dict[str, float], overrides: Mapping[str, object] | None = None
) -> ReplayConfig:
    """EKF2 parameters (as logged) onto :class:`ReplayConfig`; ``overrides`` win.

    A value that does not fit is an :class:`ExperimentError` naming the setting the user can
    change (``--set name=value``) and, when it came from the log, the EKF2 parameter."""
    mapping = {
        "EKF2_GYR_NOISE": ("gyro_noise_rad_s", 1.0), "EKF2_ACC_NOISE": ("accel_noise_m_s2", 1.0),
        "EKF2_GYR_B_NOISE": ("gyro_bias_noise_rad_s2", 1.0), "EKF2_ACC_B_NOISE": ("accel_bias_noise_m_s3", 1.0),
        "EKF2_GPS_DELAY": ("gps_delay_s", 1e-3), "EKF2_BARO_DELAY": ("baro_delay_s", 1e-3),
        "EKF2_MAG_DELAY": ("mag_delay_s", 1e-3), "EKF2_GPS_P_NOISE": ("gps_pos_noise_m", 1.0),
        "EKF2_GPS_V_NOISE": ("gps_vel_noise_m_s", 1.0), "EKF2_BARO_NOISE": ("baro_noise_m", 1.0),
        "EKF2_HEAD_NOISE": ("heading_noise_rad", 1.0), "EKF2_GPS_P_GATE": ("gate_sigma", 1.0),
        "EKF2_TAU_VEL": ("tau_vel_s", 1.0), "EKF2_TAU_POS": ("tau_pos_s", 1.0),
        "EKF2_EV_DELAY": ("ev_delay_s", 1e-3), "EKF2_RNG_DELAY": ("range_delay_s", 1e-3),
        "EKF2_EVP_NOISE": ("ev_pos_noise_m", 1.0), "EKF2_EVA_NOISE": ("ev_yaw_noise_rad", 1.0),
        "EKF2_RNG_NOISE": ("range_noise_m", 1.0), "EKF2_ABL_GYRLIM": ("accel_bias_learn_gyro_limit_rad_s", 1.0),
        "EKF2_ABL_ACCLIM": ("accel_bias_learn_accel_limit_m_s2", 1.0), "EKF2_ABL_TAU": ("accel_bias_learn_tau_s", 1.0),
    }  # fmt: skip
    values: dict[str, object] = {}
    origin: dict[str, str] = {}
    for key, (name, scale) in mapping.items():
        if key in params and math.isfinite(params[key]) and params[key] > 0:
            values[name] = params[key] * scale
            origin[name] = key
    direct = {
        "EKF2_REQ_EPH": "gps_max_eph_m", "EKF2_GPS_CHECK": "gps_check_mask", "EKF2_REQ_NSATS": "gps_min_sats",
        "EKF2_REQ_PDOP": "gps_max_pdop", "EKF2_REQ_EPV": "gps_max_epv_m", "EKF2_REQ_SACC": "gps_max_sacc_m_s",
        "EKF2_REQ_HDRIFT": "gps_max_hdrift_m_s", "EKF2_REQ_VDRIFT": "gps_max_vdrift_m_s", "EKF2_REQ_GPS_H": "gps_pass_s",
    }  # fmt: skip
    for key, name in direct.items():
        if key in params:
            v = params[key]
            values[name] = (
                int(v) if name in ("gps_check_mask", "gps_min_sats") and math.isfinite(v) else v
            )
            origin[name] = key
    if "EKF2_GPS_CTRL" in params:  # v1.14 and later: bit 1 is the GNSS altitude
        values["gps_height"] = bool(int(params["EKF2_GPS_CTRL"]) & 2)
    elif "EKF2_HGT_MODE" in params:  # earlier: the GNSS altitude only as the height reference
        values["gps_height"] = int(params["EKF2_HGT_MODE"]) == 1
    for name in overrides or {}:
        origin.pop(name, None)
    values.update(overrides or {})
    try:
        return ReplayConfig.model_validate(values)
    except ValidationError as exc:
        err = exc.errors()[0]
        name = str(err["loc"][0]) if err["loc"] else "?"
        if err["type"] == "extra_forbidden":
            known = ", ".join(ReplayConfig.model_fields)
            raise ExperimentError(
                f"replay setting {name}: unknown (the settings are: {known})"
            ) from None
        where = (
            f"the log's {origin[name]} = {params[origin[name]]:g}"
            if name in origin
            else f"got {err.get('input')!r}"
        )
        raise ExperimentError(
            f"replay setting {name} ({where}): {err['msg']}; set it with --set {name}=..."
        ) from None


@dataclass
class ReplayResult:
    """Our estimate at the current horizon (``t_ns``, ENU/FLU), the delayed states, fusion
    statistics and what was skipped."""

    t_ns: NDArray[np.int64]
    p: FloatArray
    v: FloatArray
    q_xyzw: FloatArray
    datum_lla: tuple[float, float, float]
    sources: dict[str, SourceStats]
    imu: ImuCounts
    fusion: Mapping[str, SourceFusion]
    events: list[tuple[int, str]]
    notes: list[str] = field(default_factory=list)
    replay_wall_s: float = 0.0
    gnss_checks: GnssChecks | None = None

    def counts_json(self) -> dict[str, dict[str, int]]:
        """The ``counts`` of ``metrics.json``: per source, the IMU, PX4's GNSS checks."""
        keys = ("received", "rejected_out_of_order", "rejected_invalid", "clipping_flagged")
        out = counts_json(self.sources, self.imu, imu_keys=keys)
        for src in self.sources:
            out[src].pop("rejected_unsupported")
        g = self.gnss_checks
        if g is not None:
            out["gps_checks"] = {
                "fixes": len(g.usable),
                "passed": int(g.usable.sum()),
                **g.refused_counts(),
            }
        return out


def _gps_stream(
    s: UlogSensors, cfg: ReplayConfig, gnss: GnssChecks | None
) -> list[tuple[int, int, Sample]]:
    """The fixes PX4's quality checks let through, with their accuracies as noise."""
    out: list[tuple[int, int, Sample]] = []
    g = s.gps
    if not g or gnss is None:
        return out
    d_ns = s_to_ns(cfg.gps_delay_s)
    for k in np.flatnonzero(gnss.usable).tolist():
        t = int(g["t_ns"][k])
        sh = max(float(g["eph"][k]), cfg.gps_pos_noise_m)
        # without GNSS height fusion the altitude is given no weight
        sv = max(float(g["epv"][k]), 1.5 * cfg.gps_pos_noise_m) if cfg.gps_height else 1e4
        svel = max(float(g["s_var"][k]), cfg.gps_vel_noise_m_s)
        try:
            sample = GpsSample(
                t_ns=t - d_ns,
                lat_deg=float(g["lat"][k]),
                lon_deg=float(g["lon"][k]),
                alt_m=float(g["alt"][k]),
                v_enu_m_s=g["v_enu"][k],
                sigma_h_m=sh,
                sigma_v_m=sv,
                sigma_vel_m_s=svel,
            )
        except Exception:  # a corrupt record: left out (counted by the caller as missing)
            continue
        out.append((t, len(out), sample))
    return out


def _stream(
    s: UlogSensors, cfg: ReplayConfig, gnss: GnssChecks | None, baro_ref_m: float
) -> list[tuple[int, int, Sample]]:
    """(arrival ns, order, sample) for every measurement, with times of validity; GNSS fixes
    only where PX4's quality checks let them through."""
    out = _gps_stream(s, cfg, gnss)
    seq = len(out)
    b = s.baro
    if b:
        d_ns = s_to_ns(cfg.baro_delay_s)
        for t, a in zip(b["t_ns"], b["alt"], strict=True):
            if math.isfinite(float(a)):
                # heights relative to the datum's altitude, as PX4's baro offset does
                out.append(
                    (
                        int(t),
                        seq,
                        HeightSample(
                            t_ns=int(t) - d_ns,
                            z_m=float(a) - baro_ref_m,
                            sigma_m=cfg.baro_noise_m,
                        ),
                    )
                )
                seq += 1
    m = s.mag
    if m:
        d_ns = s_to_ns(cfg.mag_delay_s)
        for t, f in zip(m["t_ns"], m["field_B"], strict=True):
            if np.isfinite(f).all() and np.linalg.norm(f) > 0:
                out.append(
                    (
                        int(t),
                        seq,
                        MagSample(
                            t_ns=int(t) - d_ns, field_B=f, sigma_heading_rad=cfg.heading_noise_rad
                        ),
                    )
                )
                seq += 1
    v = s.vision
    if v:
        d_ns = s_to_ns(cfg.ev_delay_s)
        for k in range(len(v["t_ns"])):
            var = v["var"][k]
            sig = float(np.sqrt(np.nanmax(var))) if np.isfinite(var).any() else cfg.ev_pos_noise_m
            try:
                pose = PoseSample(
                    t_ns=int(v["t_ns"][k]) - d_ns,
                    p_W_B=v["p"][k],
                    q_W_B_xyzw=v["q_xyzw"][k],
                    sigma_pos_m=max(sig, 1e-3),
                    sigma_yaw_rad=cfg.ev_yaw_noise_rad,
                    reset_counter=int(v["reset"][k]),
                )
            except Exception:
                continue
            out.append((int(v["t_ns"][k]), seq, pose))
            seq += 1
    r = s.range
    if r:
        d_ns = s_to_ns(cfg.range_delay_s)
        for k in range(len(r["t_ns"])):
            try:
                rs = RangeSample(
                    t_ns=int(r["t_ns"][k]) - d_ns,
                    range_m=float(r["range_m"][k]),
                    sigma_m=cfg.range_noise_m,
                    min_m=float(r["min_m"][k]),
                    max_m=float(r["max_m"][k]),
                )
            except Exception:  # outside its span, or garbage: not a reading
                continue
            out.append((int(r["t_ns"][k]), seq, rs))
            seq += 1
    return out


def _downsample(
    t: NDArray[np.int64], gyro: FloatArray, accel: FloatArray, clip: NDArray[np.int64], n: int
) -> tuple[NDArray[np.int64], FloatArray, FloatArray, NDArray[np.int64]]:
    """Average each run of ``n`` IMU samples into one, stamped at its last sample, its clipping
    flags ORed (what PX4's IMU down-sampler hands EKF2). A sample with a non-finite value
    spoils its group, which the estimator then refuses at its boundary and counts."""
    clip = np.asarray(clip, dtype=np.int64)
    if n == 1:
        return t, gyro, accel, clip
    m = (len(t) // n) * n
    tt = t[:m].reshape(-1, n)
    w = np.diff(np.concatenate([[t[0] - (t[1] - t[0])], t[:m]])).reshape(-1, n).astype(np.float64)
    w = np.where(w > 0, w, 0.0)
    w /= np.maximum(w.sum(axis=1, keepdims=True), 1e-12)
    g = np.einsum("kn,knj->kj", w, gyro[:m].reshape(-1, n, 3))
    a = np.einsum("kn,knj->kj", w, accel[:m].reshape(-1, n, 3))
    c = np.bitwise_or.reduce(clip[:m].reshape(-1, n), axis=1)
    return tt[:, -1].copy(), g, a, c


def _landed(s: UlogSensors, t_ns: NDArray[np.int64]) -> NDArray[np.bool_]:
    """PX4's land detector, held between its messages, at each time."""
    return held_flags(
        s.landed.get("t_ns", np.zeros(0, np.int64)), s.landed.get("landed", np.zeros(0, bool)), t_ns
    )


def gnss_checks_for(s: UlogSensors, cfg: ReplayConfig) -> GnssChecks | None:
    """PX4's GNSS quality checks over the log's fixes (None without GNSS)."""
    if not s.gps:
        return None
    c = GnssCheckConfig(
        mask=cfg.gps_check_mask,
        min_fix=cfg.min_gps_fix,
        min_sats=cfg.gps_min_sats,
        max_pdop=cfg.gps_max_pdop,
        max_eph_m=cfg.gps_max_eph_m,
        max_epv_m=cfg.gps_max_epv_m,
        max_sacc_m_s=cfg.gps_max_sacc_m_s,
        max_hdrift_m_s=cfg.gps_max_hdrift_m_s,
        max_vdrift_m_s=cfg.gps_max_vdrift_m_s,
        pass_s=cfg.gps_pass_s,
    )
    return run_gnss_checks(s.gps, _landed(s, s.gps["t_ns"]), c)


def _gnss_note(g: GnssChecks, t0_ns: int) -> str:
    refused = int((~g.usable).sum())
    why = ", ".join(
        f"{k} {v}" for k, v in sorted(g.refused_counts().items(), key=lambda kv: -kv[1])
    )
    when = (
        f"the receiver passed PX4's checks at {(g.t_qualified_ns - t0_ns) * 1e-9:.2f} s"
        if g.t_qualified_ns is not None
        else "the receiver never passed PX4's checks: GNSS not used"
    )
    return f"GNSS: {refused} of {len(g.usable)} fixes refused by PX4's quality checks ({why or 'none'}); {when}"


def _prepare_imu(
    s: UlogSensors, cfg: ReplayConfig, notes: list[str]
) -> tuple[NDArray[np.int64], FloatArray, FloatArray, NDArray[np.int64], int]:
    n_imu = len(s.imu_t_ns)
    if n_imu < 10:
        raise ExperimentError(f"{s.path}: only {n_imu} IMU samples")
    clip = s.imu_clipping if len(s.imu_clipping) == n_imu else np.zeros(n_imu, np.int64)
    t_imu, gyro, accel, clip = _downsample(
        s.imu_t_ns, s.gyro_rad_s, s.accel_m_s2, clip, cfg.imu_downsample
    )
    period_ns = int(np.median(np.diff(t_imu)))
    for k in np.flatnonzero(np.diff(t_imu) > 20 * period_ns).tolist():
        notes.append(
            f"IMU gap of {(t_imu[k + 1] - t_imu[k]) * 1e-9:.3f} s at {(t_imu[k] - s.t_start_ns) * 1e-9:.3f} s: predicted across it"
        )
    back = int(np.sum(np.diff(t_imu) <= 0))
    if back:
        notes.append(f"{back} IMU timestamps not increasing: rejected and counted")
    n_clip = int(np.count_nonzero(clip & 7))
    if n_clip:
        notes.append(
            f"accelerometer clipping flagged in {n_clip} filter steps: those axes carry "
            f"{cfg.clipped_accel_noise_m_s2:g} m/s^2 of process noise and learn no bias (PX4)"
        )
    return t_imu, gyro, accel, clip & 7, period_ns


def _datum(s: UlogSensors, gnss: GnssChecks | None, notes: list[str]) -> tuple[float, float, float]:
    """PX4's local origin when the log has one (so the frames match), else the first fix
    PX4's checks let through."""
    if s.local_origin_lla is not None:
        return s.local_origin_lla
    if gnss is not None and gnss.usable.any():
        k = int(np.flatnonzero(gnss.usable)[0])
        notes.append(
            "no PX4 local origin in the log: the first GNSS fix that passed the checks is the datum"
        )
        return (float(s.gps["lat"][k]), float(s.gps["lon"][k]), float(s.gps["alt"][k]))
    notes.append("no usable GNSS: the world origin is where the log starts")
    return (0.0, 0.0, 0.0)


def _align(
    s: UlogSensors,
    cfg: ReplayConfig,
    imu: tuple[NDArray[np.int64], FloatArray, FloatArray],
    t_align: int,
    datum: tuple[float, float, float],
    decl: float,
    gnss: GnssChecks | None,
) -> tuple[Any, FloatArray, bool]:
    """Attitude and position from the first ``align_s`` of IMU and magnetometer data (and a
    usable fix near then)."""
    t_imu, gyro, accel = imu
    idx = np.flatnonzero(t_imu <= t_align).tolist()
    align_imu = [
        ImuSample(t_ns=int(t_imu[i]), gyro_rad_s=gyro[i], accel_m_s2=accel[i])
        for i in idx
        if np.isfinite(gyro[i]).all() and np.isfinite(accel[i]).all()
    ]
    align_mag = []
    if s.mag:
        sel = (s.mag["t_ns"] <= t_align) & np.isfinite(s.mag["field_B"]).all(axis=1)
        align_mag = [
            MagSample(t_ns=int(t), field_B=f, sigma_heading_rad=cfg.heading_noise_rad)
            for t, f in zip(s.mag["t_ns"][sel], s.mag["field_B"][sel], strict=True)
        ]
    gps_enu = None
    if gnss is not None:
        ok = np.flatnonzero(gnss.usable & (s.gps["t_ns"] <= t_align + 2_000_000_000))
        if len(ok):
            k = int(ok[0])
            fix = [[s.gps["lat"][k], s.gps["lon"][k], s.gps["alt"][k]]]
            gps_enu = NavSatTransform(GeoDatum(*datum)).enu(fix)[0]
    R0, p0 = ground_alignment(
        align_imu, None, mag=align_mag, declination_rad=decl, gps_enu_m=gps_enu
    )
    return R0, p0, gps_enu is not None


def _filter(
    s: UlogSensors,
    cfg: ReplayConfig,
    period_ns: int,
    t_align: int,
    datum: tuple[float, float, float],
    decl: float,
    R0: Any,
    p0: FloatArray,
    gps_at_start: bool,
    baro_anchor_var_m2: float,
) -> tuple[NavEkf, DelayedHorizonEstimator]:
    dt = period_ns * 1e-9
    ekf_cfg = NavEkfConfig(
        gyro_sigma_rad_s=cfg.gyro_noise_rad_s,
        accel_sigma_m_s2=cfg.accel_noise_m_s2,
        gyro_bias_rw_rad_s_sqrt_s=cfg.gyro_bias_noise_rad_s2 * math.sqrt(dt),
        accel_bias_rw_m_s2_sqrt_s=cfg.accel_bias_noise_m_s3 * math.sqrt(dt),
        gate_sigma=cfg.gate_sigma,
        datum_lla=datum,
        mag_declination_rad=decl,
        reset_after_s=5.0,
        baro_bias_nsd_m_s=cfg.baro_bias_nsd_m_s,
        baro_bias_var0_m2=baro_anchor_var_m2,
        clipped_accel_sigma_m_s2=cfg.clipped_accel_noise_m_s2,
        accel_bias_learn_gyro_limit_rad_s=cfg.accel_bias_learn_gyro_limit_rad_s,
        accel_bias_learn_accel_limit_m_s2=cfg.accel_bias_learn_accel_limit_m_s2,
        accel_bias_learn_tau_s=cfg.accel_bias_learn_tau_s,
        relevel_at_rest_s=cfg.relevel_at_rest_s,
    )
    # With a barometer bias and no GNSS height the world's height origin is where the log
    # starts: the start height is known, and the anchor's uncertainty is the bias's.
    sig_z0 = (
        cfg.init_height_sigma_anchored_m
        if cfg.baro_bias_nsd_m_s is not None and not cfg.gps_height
        else cfg.init_height_sigma_m
    )
    sigmas = InitialSigmas(
        tilt_rad=cfg.init_tilt_sigma_rad,
        yaw_rad=cfg.init_yaw_sigma_rad,
        vel_m_s=cfg.init_vel_sigma_m_s,
        pos_xy_m=cfg.init_pos_sigma_gps_m if gps_at_start else cfg.init_pos_sigma_m,
        pos_z_m=sig_z0,
        gyro_bias_rad_s=cfg.init_gyro_bias_sigma_rad_s,
        accel_bias_m_s2=cfg.init_accel_bias_sigma_m_s2,
    )
    max_delay = max(
        cfg.gps_delay_s if s.gps else 0.0,
        cfg.baro_delay_s,
        cfg.mag_delay_s,
        cfg.ev_delay_s,
        cfg.range_delay_s,
    )
    horizon = HorizonConfig(
        imu_period_ns=period_ns,
        max_delay_ns=s_to_ns(max_delay),
        tau_vel_s=cfg.tau_vel_s,
        tau_pos_s=cfg.tau_pos_s,
    )
    setup = NavFilterSetup(ekf=ekf_cfg, horizon=horizon, sigmas=sigmas)
    est = build_nav_filter(setup, t0_ns=t_align, p0=p0, q0_xyzw=R0.as_quat())
    assert isinstance(est.filter, NavEkf)
    return est.filter, est


def _baro_ref(
    s: UlogSensors, cfg: ReplayConfig, t_align: int, datum_alt_m: float, z0_m: float
) -> tuple[float, float]:
    """The barometer's reading at the start height (its median over the alignment) and that
    anchor's variance by the log's barometer noise (EKF2_BARO_NOISE squared over the readings)."""
    if s.baro:
        sel = (s.baro["t_ns"] <= t_align) & np.isfinite(s.baro["alt"])
        if sel.any():
            return float(np.median(s.baro["alt"][sel])) - z0_m, cfg.baro_noise_m**2 / int(sel.sum())
    return datum_alt_m, cfg.baro_noise_m**2


def _run(
    est: DelayedHorizonEstimator,
    cfg: ReplayConfig,
    imu: tuple[NDArray[np.int64], FloatArray, FloatArray],
    clip: NDArray[np.int64],
    start: int,
    obs: list[tuple[int, int, Sample]],
    landed_at: NDArray[np.bool_],
    progress: Any,
) -> tuple[list[int], list[FloatArray], list[FloatArray], list[FloatArray]]:
    """Feed the IMU and the measurements in arrival order; the output every fifth IMU step."""
    t_imu, gyro, accel = imu
    heapq.heapify(obs)
    rows: tuple[list[int], list[FloatArray], list[FloatArray], list[FloatArray]] = ([], [], [], [])
    n_zupt = 0
    for k in range(start, len(t_imu)):
        t = int(t_imu[k])
        while obs and obs[0][0] <= t:
            est.push(heapq.heappop(obs)[2])
        if landed_at[k]:
            n_zupt += 1
            if n_zupt % 10 == 0:
                est.push(
                    VelocitySample(t_ns=t, v_W_B=np.zeros(3), sigma_m_s=cfg.zero_velocity_sigma_m_s)
                )
        if clip[k]:  # PX4's clipping flags go with the sample to the delayed horizon
            est.push_raw(
                ClippedImuSample,
                t_ns=t,
                gyro_rad_s=gyro[k],
                accel_m_s2=accel[k],
                accel_clip_axes=int(clip[k]),
            )
        else:
            est.push_raw(ImuSample, t_ns=t, gyro_rad_s=gyro[k], accel_m_s2=accel[k])
        if k % 5 == 0:
            o = est.output_nav()
            rows[0].append(o.t_ns)
            rows[1].append(o.pos)
            rows[2].append(o.vel)
            rows[3].append(quat_xyzw_from_matrix(o.att.reshape(3, 3)))
        if progress and k % 2000 == 0:
            progress(k, len(t_imu), "IMU samples")
    return rows


def replay(s: UlogSensors, cfg: ReplayConfig, *, progress: Any = None) -> ReplayResult:
    notes = list(s.notes)
    t_wall0 = time.perf_counter()
    t_imu, gyro_all, accel_all, clip_all, period_ns = _prepare_imu(s, cfg, notes)
    gnss = gnss_checks_for(s, cfg)
    if gnss is not None:
        notes.append(_gnss_note(gnss, s.t_start_ns))
    datum = _datum(s, gnss, notes)
    decl = (
        cfg.mag_declination_rad
        if cfg.mag_declination_rad is not None
        else (s.earth_field_declination_rad or 0.0)
    )
    t_align = int(t_imu[0]) + s_to_ns(cfg.align_s)
    imu = (t_imu, gyro_all, accel_all)
    R0, p0, gps_at_start = _align(s, cfg, imu, t_align, datum, decl, gnss)
    baro_ref, baro_anchor_var = _baro_ref(s, cfg, t_align, datum[2], float(p0[2]))
    ekf, est = _filter(
        s, cfg, period_ns, t_align, datum, decl, R0, p0, gps_at_start, baro_anchor_var
    )
    obs = [o for o in _stream(s, cfg, gnss, baro_ref) if o[0] > t_align]
    landed_at = _landed(s, t_imu) & cfg.zero_velocity_when_landed
    start = int(np.searchsorted(t_imu, t_align, side="right"))
    rows_t, rows_p, rows_v, rows_q = _run(est, cfg, imu, clip_all, start, obs, landed_at, progress)
    wall = time.perf_counter() - t_wall0
    if est.rejected_invalid:
        notes.append(f"refused at the boundary (non-finite values): {est.rejected_invalid}")
    imu_counts = ImuCounts(
        received=len(t_imu) - start,
        rejected_out_of_order=est.imu_rejected_out_of_order,
        rejected_invalid=est.rejected_invalid.get("ImuSample", 0),
        clipping_flagged=int(np.count_nonzero(s.imu_clipping)),
    )
    return ReplayResult(
        t_ns=np.array(rows_t, dtype=np.int64),
        p=np.array(rows_p),
        v=np.array(rows_v),
        q_xyzw=np.array(rows_q),
        datum_lla=datum,
        sources={src: est.stats(src) for src in est.sources},
        imu=imu_counts,
        fusion=fusion_arrays(est.fusion_log),
        events=list(ekf.events),
        notes=notes,
        replay_wall_s=wall,
        gnss_checks=gnss,
    )
