"""The main job's navigation study (``quadnav run``): its seeds run, their metrics, plots and
run folders."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import ConfigError, EvalError
from quadnav.estimation.chi2 import chi2_pdf, chi2_ppf
from quadnav.estimation.horizon import SourceStats
from quadnav.estimation.nav_filter import ImuCounts
from quadnav.eval.fusion_reference import random_walk_fusion_reference
from quadnav.eval.metrics import nees
from quadnav.eval.na import Metric, max_or_na, mean_or_na, median_or_na, na, rms_or_na
from quadnav.eval.report import ReportSection, ReportTable, write_report
from quadnav.eval.vio_metrics import ape_summary
from quadnav.experiments.nav import NavRunResult, NavScenario, run_nav
from quadnav.experiments.nav_channels import is_pseudo_source
from quadnav.experiments.seeds import run_tasks
from quadnav.experiments.vio_flight import VioRecord, flight_rig
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.config import dump_config
from quadnav.io.mavlink import MavlinkLink
from quadnav.io.run_folder import (
    append_jsonl,
    create_run_folder,
    finish_run_folder,
    write_csv,
    write_json,
    write_text,
)
from quadnav.io.trajectory_io import write_tum
from quadnav.messages import OdometrySample
from quadnav.viz.background import RecordingProcess
from quadnav.viz.recording import require_rerun
from quadnav.viz.stream import RerunOptions

__all__ = [
    "NavMetrics",
    "NavStudy",
    "NavSummary",
    "OdometryLink",
    "nav_metrics",
    "plot_nav_run",
    "refusal_counts",
    "reports_in_flight",
    "run_nav_study",
    "summarize_nav_seeds",
]

FloatArray = NDArray[np.float64]
Progress = Callable[[int, int, str], None]


def _t_s(r: NavRunResult) -> FloatArray:
    return np.asarray(r.t_ns * 1e-9, dtype=np.float64)


@dataclass(frozen=True, slots=True, kw_only=True)
class NavMetrics:
    """The issue-5 numbers of one flight (a metric no flight can give is an "n/a: why" string)."""

    seed: int
    output_rmse_with_vision_m: Metric
    output_rmse_m: Metric
    bias_error_fraction_60s: dict[str, Metric]
    dropout_end_error_m: list[Metric]
    dropout_recovery_s: list[Metric]
    hold_max_horizontal_error_m: Metric
    delayed_rmse_m: Metric
    attitude_rmse_deg: Metric
    nees_mean: Metric
    nis_above_95pct_gate: dict[str, float]
    sources: dict[str, SourceStats]
    imu: ImuCounts
    filter_events: list[str]
    landed_at_m: list[float]
    end_horizontal_error_m: float
    distance_flown_m: float
    drift_percent: Metric
    end_position_error_m: float = math.nan  # 3-D, output predictor against the truth
    vio_counts: dict[str, int] = field(default_factory=dict)  # frames, states, resets...
    vio_events: list[str] = field(default_factory=list)
    #: the odometry's own estimate against the truth (the rig's body, its optimised frames):
    #: translation APE after a 4-DoF (position and yaw) alignment, RMSE
    vio_ate_m: Metric = field(default_factory=lambda: na("no visual odometry"))
    vio_alone_m: Metric = field(default_factory=lambda: na("no visual odometry"))
    #: with GPS: this odometry fused with the scenario's GPS positions by a random-walk filter
    #: at the rate that suits this flight, chosen with hindsight (a reference, not a bound:
    #: :mod:`quadnav.eval.fusion_reference`), and that rate (m^2/s an axis)
    vio_gps_reference_m: Metric = field(default_factory=lambda: na("no visual odometry"))
    vio_gps_reference_rate: Metric = field(default_factory=lambda: na("no visual odometry"))
    #: with loop closure: its places judged against the truth (``loop_precision``,
    #: ``loop_recall``, the measurements' median errors; :mod:`quadnav.eval.loop_eval`)
    vio_loop: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, object]:
        """The flat record ``metrics.json`` and ``seeds.jsonl`` hold (``counts`` per source)."""
        out = {
            f: getattr(self, f) for f in self.__dataclass_fields__ if f not in ("sources", "imu")
        }
        counts: dict[str, dict[str, int]] = {
            src: {k: getattr(st, k) for k in _COUNT_KEYS} for src, st in self.sources.items()
        }
        counts["imu"] = {"rejected_out_of_order": self.imu.rejected_out_of_order,
                         "rejected_invalid": self.imu.rejected_invalid}  # fmt: skip
        return {**out, "counts": counts}


_COUNT_KEYS = ("received", "fused", "rejected_gate", "rejected_too_old", "rejected_unsupported")


def _dropout_metrics(
    r: NavRunResult, t: FloatArray, err: FloatArray, airborne: NDArray[np.bool_]
) -> tuple[NDArray[np.bool_], list[Metric], list[Metric]]:
    """The samples in the air with vision, and per dropout the error at its end and the time
    until the error is back under 3 cm."""
    sc = r.scenario
    with_vision = airborne.copy()
    dropout_end: list[Metric] = []
    recovery: list[Metric] = []
    for a, b in sc.vision.dropouts_s if sc.vision.enabled else []:
        with_vision &= ~((t >= a) & (t < b + 1.0))
        if not t[0] <= b <= t[-1]:
            continue  # the flight ended before vision came back: no end, no recovery
        k = int(np.argmin(np.abs(t - b)))
        dropout_end.append(float(err[k]))
        back = np.flatnonzero((t > b) & (err < 0.03))
        recovery.append(float(t[back[0]] - b) if len(back) else na("never back under 3 cm"))
    return with_vision, dropout_end, recovery


def _hold_mask(r: NavRunResult, t: FloatArray) -> NDArray[np.bool_]:
    """The holds at flight height above the take-off point (after the climb and before the
    descent), from their first second on. The corner stops of the square are not hovers. A
    plan that says where it hovers (thesis 003's take-off and forward) says so itself."""
    if r.hover is not None:
        return r.hover
    above_start = np.all(np.abs(r.ref_p[:, 0:2] - r.ref_p[0, 0:2]) < 1e-9, axis=1)
    still = (
        np.concatenate([[False], np.all(np.diff(r.ref_p, axis=0) == 0, axis=1)])
        & (r.ref_p[:, 2] >= r.scenario.plan.height_m - 1e-9)
        & above_start
    )
    hold = np.zeros(len(t), dtype=bool)
    start = None
    for i, s in enumerate(still):
        if s and start is None:
            start = t[i]
        if not s:
            start = None
        hold[i] = s and start is not None and t[i] - start >= 1.0
    return hold


def _nis_ratios(r: NavRunResult) -> dict[str, float]:
    """Per measured source, the fraction of NIS above its 95 % chi-square gate."""
    ratios = {}
    for src, f in r.fusion.items():
        if len(f) and not is_pseudo_source(src):  # (standing still is not a measurement)
            gate95 = chi2_ppf(0.95, f.dof)
            ratios[src] = float(np.mean(f.nis > gate95))
    return ratios


def _drift(r: NavRunResult) -> tuple[float, float, Metric]:
    """The horizontal error of the output at the end of the flight (landed), the horizontal
    distance flown and the first over the second in percent."""
    end = float(np.linalg.norm(r.output_p[-1, :2] - r.truth_p[-1, :2]))
    dist = float(np.sum(np.linalg.norm(np.diff(r.truth_p[:, :2], axis=0), axis=1)))
    pct = 100.0 * end / dist if dist > 0.1 else na("flew less than 0.1 m")
    return end, dist, pct


def _rows(mask: NDArray[np.bool_]) -> NDArray[np.bool_] | slice:
    """The rows of ``mask``: a slice when they are one run (the flight's airborne part: a view
    of the covariances, not a copy of tens of megabytes), else the mask itself."""
    idx = np.flatnonzero(mask)
    if len(idx) and idx[-1] - idx[0] + 1 == len(idx):
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return mask


def nav_metrics(r: NavRunResult) -> NavMetrics:
    """The issue-5 numbers of one flight."""
    t = _t_s(r)
    err = np.linalg.norm(r.output_p - r.truth_p, axis=1)
    # In the air: sitting on the ground and touching down are not what the filter is for.
    airborne = r.truth_p[:, 2] > 0.1
    with_vision, dropout_end, recovery = _dropout_metrics(r, t, err, airborne)
    horiz = np.abs(r.truth_p[_hold_mask(r, t), 0:2] - r.ref_p[_hold_mask(r, t), 0:2])
    # NEES at the delayed horizon in the air (its own times): ground contact (touch-down) is an
    # external force the filter does not model.
    airborne_delayed = np.interp(r.t_delayed_ns, r.t_ns, r.truth_p[:, 2]) > 0.05
    ok = np.isfinite(r.delayed_err).all(axis=1) & airborne_delayed
    ok_P = ok & np.isfinite(r.delayed_P).all(axis=(1, 2))
    att_err = (Rotation.from_quat(r.output_q).inv() * Rotation.from_quat(r.truth_q)).magnitude()
    in_air = "no samples in the air"
    att_rmse = rms_or_na(att_err[airborne], in_air)
    no_cov = "no covariance in the air (the estimator gives none)"
    end, dist, drift = _drift(r)
    return NavMetrics(
        seed=r.seed,
        output_rmse_with_vision_m=rms_or_na(err[with_vision], "no samples in the air with vision")
        if r.scenario.vision.enabled
        else na("vision disabled"),
        output_rmse_m=rms_or_na(err[airborne], in_air),
        bias_error_fraction_60s=_bias_error_fractions(r),
        dropout_end_error_m=dropout_end,
        dropout_recovery_s=recovery,
        hold_max_horizontal_error_m=max_or_na(
            horiz, "no hold above the take-off point of over 1 s"
        ),
        delayed_rmse_m=rms_or_na(np.linalg.norm(r.delayed_err[ok, 6:9], axis=1), in_air),
        attitude_rmse_deg=att_rmse if isinstance(att_rmse, str) else math.degrees(att_rmse),
        nees_mean=mean_or_na(
            nees(r.delayed_err[_rows(ok_P)], r.delayed_P[_rows(ok_P)]) if ok_P.any() else [],
            no_cov,
        ),
        nis_above_95pct_gate=_nis_ratios(r),
        sources=dict(r.sources),
        imu=r.imu,
        filter_events=[f"{t * 1e-9:.3f} s: {msg}" for t, msg in r.events],
        landed_at_m=r.truth_p[-1].tolist(),
        end_horizontal_error_m=end,
        distance_flown_m=dist,
        drift_percent=drift,
        end_position_error_m=float(np.linalg.norm(r.output_p[-1] - r.truth_p[-1])),
        **_vio_metrics(r),
    )


def _vio_metrics(r: NavRunResult) -> dict[str, Any]:
    """What the VIO did: frames given, states returned, re-initialisations (its reset counter
    at the end), odometry refused at the boundary, its events."""
    v = r.vio
    if v is None:
        return {}
    resets = int(v.reset_counter[-1]) if len(v.reset_counter) else 0
    kinds = [text.split(":", 1)[0] for _, text in v.events]
    counts = {"frames": v.frames, "states": v.states, "resets": resets,
              "rejected_invalid": v.rejected_invalid, "failures": kinds.count("failure"),
              "reinitialized": kinds.count("reinitialized")}  # fmt: skip
    if v.loop is not None:  # (loop closure: its output's resets count its corrections too)
        lp = v.loop
        counts |= {
            "loops": int(lp["accepted"]), "loops_rejected": sum(lp["rejected_by_stage"].values()),
            "relocalized": len(lp["joins"]), "map_keyframes": int(lp["map_keyframes"]),
            "graph_failures": int(lp["graph_failures"]),
        }  # fmt: skip
    return {
        "vio_counts": counts,
        "vio_events": [f"{t * 1e-9:.3f} s: {msg}" for t, msg in v.events],
        "vio_loop": dict((v.loop or {}).get("evaluation") or {}),
        "vio_ate_m": _odometry_ate(v),
        "vio_alone_m": _odometry_alone(v),
        **_gps_reference(r.scenario, v),
    }


def _gps_reference(sc: NavScenario, v: VioRecord) -> dict[str, Metric]:
    """With GPS: :func:`~quadnav.eval.fusion_reference.random_walk_fusion_reference` of the odometry
    alone's errors (its states' times on the flight's clock) and the scenario's GPS."""
    if not sc.gps.enabled:
        why = na("no GPS")
        return {"vio_gps_reference_m": why, "vio_gps_reference_rate": why}
    alone = _odometry_alone_positions(v)
    if isinstance(alone, str):
        return {"vio_gps_reference_m": alone, "vio_gps_reference_rate": alone}
    t_ns, est, truth = alone
    g = sc.gps
    try:
        b = random_walk_fusion_reference(
            t_ns, est - truth, (g.sigma_h_m, g.sigma_h_m, g.sigma_v_m), g.rate_hz,
            outages_s=g.outages_s,
        )  # fmt: skip
    except EvalError as exc:  # (a metric the flight's states cannot give does not end the run)
        why = na(str(exc))
        return {"vio_gps_reference_m": why, "vio_gps_reference_rate": why}
    return {"vio_gps_reference_m": b.rmse_m, "vio_gps_reference_rate": b.rate_m2_s}


def _odometry_ate(v: VioRecord) -> Metric:
    """The odometry's own ATE: its positions against the true ones of the rig's body at the
    same frames, RMSE after a 4-DoF alignment (its world is level: the VIO's by gravity, the
    SLAM's the vehicle's at rest on the ground)."""
    ok = np.isfinite(v.truth_p_W_B).all(axis=1)
    if ok.sum() < 3:
        return na("fewer than 3 odometry states")
    est = Trajectory(t_ns=v.t_ns[ok], p_W_B=v.p_W_B[ok], q_W_B_xyzw=v.q_W_B_xyzw[ok])
    ref = Trajectory(t_ns=v.t_ns[ok], p_W_B=v.truth_p_W_B[ok], q_W_B_xyzw=v.q_W_B_xyzw[ok])
    return ape_summary(ref, est, "4dof").rmse_m


def _odometry_alone(v: VioRecord) -> Metric:
    """What flying on the odometry alone would give: its positions against the truth's, RMSE
    with its world put on the truth's at its first state (position and heading; its world is
    level), as a vehicle does that starts its odometry where it stands, facing a known way.
    After a reset (a new world) the odometry goes on from where it last was: its new world put
    at the last pose it gave before, as a vehicle on it alone would carry on (the motion while it
    gave nothing counts as error: nothing else knew it)."""
    alone = _odometry_alone_positions(v)
    if isinstance(alone, str):
        return alone
    _, est, p_ref = alone
    return float(np.sqrt(np.mean(np.sum((est - p_ref) ** 2, axis=1))))


def _odometry_alone_positions(
    v: VioRecord,
) -> tuple[NDArray[np.int64], FloatArray, FloatArray] | str:
    """:func:`_odometry_alone`'s states: their times (ns), positions and the true ones (or why
    there are none)."""
    ok = np.isfinite(v.truth_p_W_B).all(axis=1)
    if ok.sum() < 3:
        return na("fewer than 3 odometry states")
    p, q, resets = v.p_W_B[ok], v.q_W_B_xyzw[ok], v.reset_counter[ok]
    p_ref, q_ref = v.truth_p_W_B[ok], v.truth_q_W_B_xyzw[ok]
    est = np.empty_like(p)
    anchor_p, anchor_q = p_ref[0], q_ref[0]  # where the first world is put: the truth
    starts = np.flatnonzero(np.r_[True, np.diff(resets) != 0])
    for a, b in zip(starts, np.r_[starts[1:], len(p)], strict=True):
        R = Rotation.from_quat(anchor_q) * Rotation.from_quat(q[a]).inv()
        Rz = Rotation.from_euler("z", float(R.as_euler("ZYX")[0]))
        est[a:b] = Rz.apply(p[a:b] - p[a]) + anchor_p
        anchor_p = est[b - 1]
        anchor_q = (Rz * Rotation.from_quat(q[b - 1])).as_quat()
    return v.t_ns[ok], est, p_ref


def _bias_error_fractions(r: NavRunResult) -> dict[str, Metric]:
    """The delayed estimate's bias errors 60 s after alignment (or at the end of a shorter
    flight), relative to the true biases."""
    t_60 = r.t_align_ns + 60_000_000_000
    valid = np.flatnonzero(np.isfinite(r.delayed_err).all(axis=1) & (r.t_delayed_ns <= t_60))
    out: dict[str, Metric] = {}
    for name, est_sl, err_sl in (
        ("gyro", slice(10, 13), slice(9, 12)),
        ("accel", slice(13, 16), slice(12, 15)),
    ):
        if not len(valid):
            out[name] = na("no delayed estimate after alignment")
            continue
        e = r.delayed_err[valid[-1], err_sl]
        true = r.delayed_x[valid[-1], est_sl] + e
        out[name] = float(np.linalg.norm(e) / max(float(np.linalg.norm(true)), 1e-12))
    return out


def _shade_dropouts(r: NavRunResult, ax: Axes) -> None:
    sc = r.scenario
    for a, b in sc.vision.dropouts_s if sc.vision.enabled else []:
        ax.axvspan(a, b, color="tab:red", alpha=0.12)


def _save(fig: Figure, path: Path) -> Path:
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _plot_position(r: NavRunResult, t: FloatArray, path: Path) -> Path:
    fig, axes = plt.subplots(3, 1, figsize=(11, 8), sharex=True, constrained_layout=True)
    for k, ax in enumerate(axes):
        ax.plot(t, r.truth_p[:, k], "--", label="truth")
        ax.plot(t, r.output_p[:, k], label="output predictor")
        ax.plot(t, r.ref_p[:, k], ":", color="0.4", label="setpoint")
        _shade_dropouts(r, ax)
        ax.set_ylabel(f"{'xyz'[k]} (m)")
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("t (s)")
    fig.suptitle(f"{r.scenario.name} seed {r.seed}: position (red: vision dropouts)")
    return _save(fig, path)


def _plot_errors(r: NavRunResult, t: FloatArray, path: Path) -> Path:
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(11, 7), sharex=True, constrained_layout=True)
    ax1.plot(t, np.linalg.norm(r.output_p - r.truth_p, axis=1), label="output predictor - truth")
    ok = np.isfinite(r.delayed_err).all(axis=1)
    td = r.t_delayed_ns * 1e-9
    ax1.plot(
        td[ok], np.linalg.norm(r.delayed_err[ok, 6:9], axis=1), label="delayed EKF - delayed truth"
    )
    sig = np.sqrt(np.trace(r.delayed_P[ok][:, 6:9, 6:9], axis1=1, axis2=2))
    ax1.plot(td[ok], sig, ":", label="EKF 1 sigma")
    _shade_dropouts(r, ax1)
    ax1.set_yscale("log")
    ax1.set_ylabel("position error (m)")
    ax1.legend(fontsize=8)
    ax1.grid(True, which="both", alpha=0.3)
    att = (Rotation.from_quat(r.output_q).inv() * Rotation.from_quat(r.truth_q)).magnitude()
    ax2.plot(t, np.degrees(att))
    _shade_dropouts(r, ax2)
    ax2.set_ylabel("attitude error (deg)")
    ax2.set_xlabel("t (s)")
    ax2.grid(True, alpha=0.3)
    return _save(fig, path)


def _plot_innovations(r: NavRunResult, srcs: list[str], path: Path) -> Path:
    """Innovation test ratios per source (1 = the gate), and the NIS against its chi-square."""
    fig, axes = plt.subplots(
        len(srcs),
        2,
        figsize=(12, 2.6 * len(srcs)),
        squeeze=False,
        gridspec_kw={"width_ratios": [3, 1]},
    )
    # (fixed margins: a constrained layout of these log axes cost most of a second a flight)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.3 / len(srcs), top=1 - 0.25 / len(srcs),
                        wspace=0.15, hspace=0.25)  # fmt: skip
    for row, src in zip(axes, srcs, strict=True):
        f = r.fusion[src]
        ts = f.t_obs_ns * 1e-9
        ok = f.accepted
        row[0].semilogy(ts[ok], np.maximum(f.test_ratio[ok], 1e-6), ".", ms=2, label="fused")
        row[0].semilogy(ts[~ok], f.test_ratio[~ok], "x", color="tab:red", ms=4, label="rejected")
        row[0].axhline(1.0, color="k", lw=0.8)
        row[0].set_ylabel(f"{src}\ntest ratio")
        row[0].grid(True, which="both", alpha=0.3)
        _shade_dropouts(r, row[0])
        dof = int(np.max(f.dof))
        nis = f.nis[ok]
        hi = float(chi2_ppf(0.999, dof))
        counts, _, _ = row[1].hist(nis[nis < hi], bins=40, density=True, alpha=0.6, label="NIS")
        xs = np.linspace(1e-3, hi, 200)
        row[1].plot(xs, chi2_pdf(xs, dof), "k", lw=1, label=f"chi2({dof})")
        row[1].set_ylim(0, 1.3 * float(np.max(counts, initial=0.1)))
        row[1].legend(fontsize=7)
    axes[0][0].legend(fontsize=7)
    axes[-1][0].set_xlabel("time of validity (s)")
    fig.suptitle(f"{r.scenario.name} seed {r.seed}: innovation test ratios (gate at 1)")
    return _save(fig, path)


def _plot_top_view(r: NavRunResult, path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(7, 7), constrained_layout=True)
    ax.plot(r.truth_p[:, 0], r.truth_p[:, 1], "--", label="truth")
    ax.plot(r.output_p[:, 0], r.output_p[:, 1], label="output predictor")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_nav_run(r: NavRunResult, folder: Path) -> list[Path]:
    """The flight's plots: position, errors (with the EKF's sigma), innovations, top view."""
    t = _t_s(r)
    paths = [
        _plot_position(r, t, folder / "position.png"),
        _plot_errors(r, t, folder / "errors.png"),
    ]
    srcs = [s for s in r.fusion if len(r.fusion[s])]
    if srcs:
        paths.append(_plot_innovations(r, srcs, folder / "innovations.png"))
    paths.append(_plot_top_view(r, folder / "top_view.png"))
    return paths


def _write_series(r: NavRunResult, folder: Path) -> None:
    cols: dict[str, NDArray[Any]] = {"t_ns": r.t_ns}
    for name, arr in (("truth", r.truth_p), ("output", r.output_p), ("ref", r.ref_p)):
        for k, a in enumerate("xyz"):
            cols[f"{name}_{a}_m"] = arr[:, k]
    write_csv(folder / "positions.csv", cols)
    d: dict[str, NDArray[Any]] = {"t_ns": r.t_delayed_ns, "t_now_ns": r.t_ns}
    names = [
        "x_m",
        "y_m",
        "z_m",
        "vx_m_s",
        "vy_m_s",
        "vz_m_s",
        "qx",
        "qy",
        "qz",
        "qw",
        "bgx",
        "bgy",
        "bgz",
        "bax",
        "bay",
        "baz",
    ]
    xd = r.delayed_x
    for k, n in enumerate(names):
        d[n] = xd[:, k]
    for k, n in zip(range(6, 9), ("x", "y", "z"), strict=True):
        d[f"var_{n}"] = r.delayed_P[:, k, k]
    # The delayed horizon waits at alignment time for the buffer to fill: keep one row per time.
    moved = np.flatnonzero(np.diff(r.t_delayed_ns, prepend=r.t_delayed_ns[0] - 1) != 0)
    write_csv(folder / "delayed.csv", {k: v[moved] for k, v in d.items()})
    for src, f in r.fusion.items():
        cols_i: dict[str, NDArray[Any]] = {
            "t_ns": f.t_obs_ns, "nis": f.nis, "test_ratio": f.test_ratio, "accepted": f.accepted,
        }  # fmt: skip
        for k in range(f.innovation.shape[1]):
            cols_i[f"innovation_{k}"] = f.innovation[:, k]
        write_csv(folder / f"innovations_{src}.csv", cols_i)
    write_tum(folder / "truth.tum", Trajectory(t_ns=r.t_ns, p_W_B=r.truth_p, q_W_B_xyzw=r.truth_q))
    write_tum(
        folder / "output.tum", Trajectory(t_ns=r.t_ns, p_W_B=r.output_p, q_W_B_xyzw=r.output_q)
    )
    if r.vio is not None and len(r.vio.t_ns):
        # the VIO's own estimate: the rig's body in the VIO's world, at its optimised frames
        v = r.vio
        write_tum(
            folder / "vio.tum", Trajectory(t_ns=v.t_ns, p_W_B=v.p_W_B, q_W_B_xyzw=v.q_W_B_xyzw)
        )


def _write_sensor_streams(r: NavRunResult, folder: Path) -> None:
    """Every sample the estimator was given, one CSV per kind (``sensors_<kind>.csv``), in the
    world and body frames of the run; ``t_ns`` is each sample's time of validity."""
    if not r.stream:
        return
    kinds: dict[str, list[Any]] = {}
    for smp in r.stream:
        kinds.setdefault(type(smp).__name__, []).append(smp)
    fields = {
        "ImuSample": ("imu", [("gyro", "gyro_rad_s", "xyz"), ("accel", "accel_m_s2", "xyz")]),
        "PoseSample": ("vision", [("p", "p_W_B", "xyz"), ("q", "q_W_B_xyzw", "xyzw")]),
        "OdometrySample": ("vio", [("p", "p_W_B", "xyz"), ("q", "q_W_B_xyzw", "xyzw"), ("v", "v_W_B", "xyz"), ("reset_counter", "reset_counter", "")]),
        "HeightSample": ("baro", [("z_m", "z_m", "")]),
        "GpsSample": ("gps", [("lat_deg", "lat_deg", ""), ("lon_deg", "lon_deg", ""), ("alt_m", "alt_m", ""), ("v", "v_enu_m_s", "xyz")]),
        "MagSample": ("mag", [("field", "field_B", "xyz")]),
        "RangeSample": ("range", [("range_m", "range_m", "")]),
    }  # fmt: skip
    for kind, samples in kinds.items():
        if kind not in fields:
            continue
        name, spec = fields[kind]
        cols: dict[str, NDArray[Any]] = {
            "t_ns": np.array([x.t_ns for x in samples], dtype=np.int64)
        }
        for col, attr, axes in spec:
            vals = np.array([getattr(x, attr) for x in samples], dtype=np.float64)
            if axes:
                for k, a in enumerate(axes):
                    cols[f"{col}_{a}"] = vals[:, k]
            else:
                cols[col] = vals
        write_csv(folder / f"sensors_{name}.csv", cols)


def _worst(values: list[Metric], none: str) -> Metric:
    """The worst case over dropouts: a dropout never recovered from beats any number."""
    never = [v for v in values if isinstance(v, str)]
    return never[0] if never else median_or_na(values, worst=True) if values else na(none)


@dataclass(frozen=True, slots=True, kw_only=True)
class NavSummary:
    """Medians over seeds (worst cases where marked); metrics no seed has say why."""

    seeds: int
    output_rmse_m: Metric
    output_rmse_with_vision_m: Metric
    dropout_end_error_max_m: Metric
    dropout_recovery_max_s: Metric
    hold_max_horizontal_error_m: Metric
    delayed_rmse_m: Metric
    attitude_rmse_deg: Metric
    nees_mean: Metric
    nees_state_dim: int
    gyro_bias_error_fraction_median: Metric
    nis_above_95pct_gate: dict[str, float]
    accel_bias_error_fraction_median: Metric
    end_horizontal_error_m: Metric
    drift_percent: Metric
    end_position_error_m: Metric
    vio_ate_m: Metric
    vio_alone_m: Metric
    vio_gps_reference_m: Metric
    # what was refused and reset, summed over the seeds (non-zero counts only), and the
    # filter's own log of each seed ("seed N, t s: what")
    refused: dict[str, int] = field(default_factory=dict)
    filter_events: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, object]:
        return {f: getattr(self, f) for f in self.__dataclass_fields__}


#: Each refusal of a source's samples, as the terminal and the report name it.
_REFUSALS = (
    ("rejected_gate", "refused by the innovation gate"),
    ("rejected_too_old", "refused as older than the buffer"),
    ("rejected_unsupported", "refused as unsupported"),
    ("dropped_overflow", "dropped, the buffer full"),
)


def refusal_counts(per_seed: list[NavMetrics]) -> dict[str, int]:
    """What became of the samples the filter did not fuse, and how often it reset, summed over
    the seeds; the counts that are not zero, named for a reader (``"gps: refused by the
    innovation gate"``)."""
    out: dict[str, int] = {}

    def add(label: str, n: int) -> None:
        out[label] = out.get(label, 0) + n

    for m in per_seed:
        for src, st in m.sources.items():
            for key, what in _REFUSALS:
                add(f"{src}: {what}", getattr(st, key))
        add("imu: refused out of order (repeated or late)", m.imu.rejected_out_of_order)
        add("imu: refused as invalid (NaN, out of range)", m.imu.rejected_invalid)
        add("filter: resets, re-anchorings and re-levellings", len(m.filter_events))
        add("vio: re-initialisations", m.vio_counts.get("resets", 0))
        add("vio: tracking lost", m.vio_counts.get("failures", 0))
        add(
            "vio: relocalized (or started again) after a loss", m.vio_counts.get("reinitialized", 0)
        )
        add("vio: odometry refused as non-finite", m.vio_counts.get("rejected_invalid", 0))
    return {k: n for k, n in out.items() if n}


def _nis_medians(per_seed: list[NavMetrics]) -> dict[str, float]:
    """Per source, the median over the seeds that fused it of its share of innovations beyond
    the 95 % gate."""
    sources = dict.fromkeys(src for m in per_seed for src in m.nis_above_95pct_gate)
    return {
        src: float(np.median([m.nis_above_95pct_gate[src] for m in per_seed
                              if src in m.nis_above_95pct_gate]))
        for src in sources
    }  # fmt: skip


def summarize_nav_seeds(per_seed: list[NavMetrics]) -> NavSummary:
    """Medians over seeds (the maximum for the worst cases); metrics no seed has say why."""
    no_dropout = "no dropout ended during the flight"
    ends: list[Metric] = [x for m in per_seed for x in m.dropout_end_error_m]
    recs: list[Metric] = [x for m in per_seed for x in m.dropout_recovery_s]
    return NavSummary(
        seeds=len(per_seed),
        output_rmse_m=median_or_na(m.output_rmse_m for m in per_seed),
        output_rmse_with_vision_m=median_or_na(m.output_rmse_with_vision_m for m in per_seed),
        dropout_end_error_max_m=_worst(ends, no_dropout),
        dropout_recovery_max_s=_worst(recs, no_dropout),
        hold_max_horizontal_error_m=median_or_na(
            (m.hold_max_horizontal_error_m for m in per_seed), worst=True
        ),
        delayed_rmse_m=median_or_na(m.delayed_rmse_m for m in per_seed),
        attitude_rmse_deg=median_or_na(m.attitude_rmse_deg for m in per_seed),
        nees_mean=median_or_na(m.nees_mean for m in per_seed),
        nees_state_dim=15,
        gyro_bias_error_fraction_median=median_or_na(
            m.bias_error_fraction_60s["gyro"] for m in per_seed
        ),
        nis_above_95pct_gate=_nis_medians(per_seed),
        accel_bias_error_fraction_median=median_or_na(
            m.bias_error_fraction_60s["accel"] for m in per_seed
        ),
        end_horizontal_error_m=median_or_na(m.end_horizontal_error_m for m in per_seed),
        drift_percent=median_or_na(m.drift_percent for m in per_seed),
        end_position_error_m=median_or_na(m.end_position_error_m for m in per_seed),
        vio_ate_m=median_or_na(m.vio_ate_m for m in per_seed),
        vio_alone_m=median_or_na(m.vio_alone_m for m in per_seed),
        vio_gps_reference_m=median_or_na(m.vio_gps_reference_m for m in per_seed),
        refused=refusal_counts(per_seed),
        filter_events=[f"seed {m.seed}, {e}" for m in per_seed for e in m.filter_events],
    )


@dataclass(frozen=True, slots=True)
class NavStudy:
    run_dir: Path
    per_seed: list[NavMetrics]
    summary: NavSummary
    mavlink_sent: dict[str, int] = field(default_factory=dict)  # messages sent, by name
    mavlink_traffic: str = ""  # the link's traffic in words (io.mavlink.describe_traffic)


def _one(sc: NavScenario, seed: int) -> NavRunResult:
    # the first seed's sensor streams go into the run folder
    return run_nav(sc, seed, record_stream=seed == sc.seed)


class OdometryLink:
    """The VIO's odometry to an autopilot as a companion computer sends it: a heartbeat every
    second of flight, and each odometry sample as it is made (ODOMETRY, MAV_ESTIMATOR_TYPE_VIO)."""

    def __init__(self, link: MavlinkLink) -> None:
        self.link = link
        self._next_heartbeat_ns: int | None = None

    def __call__(self, odo: OdometrySample) -> None:
        if self._next_heartbeat_ns is None or odo.t_ns >= self._next_heartbeat_ns:
            self.link.heartbeat()
            self._next_heartbeat_ns = odo.t_ns + 1_000_000_000
        self.link.send_odometry_sample(odo)


def _in_process(
    sc: NavScenario, progress: Progress | None, n_seeds: int, sink: OdometryLink | None
) -> Callable[[NavScenario, int], NavRunResult]:
    """One seed flown here, reporting its progress through the flight (in hundredths of
    seeds); the first seed's odometry also to ``sink``."""

    def one(scenario: NavScenario, seed: int) -> NavRunResult:
        k = seed - sc.seed

        def flown(frac: float) -> None:
            if progress is not None:
                progress(100 * k + int(100 * frac), 100 * n_seeds, f"seed {seed}")

        first = seed == sc.seed
        return run_nav(
            scenario,
            seed,
            record_stream=first,
            odometry_sink=sink if first else None,
            progress=flown,
        )

    return one


def _write_study(
    sc: NavScenario,
    run_dir: Path,
    first: NavRunResult,
    per_seed: list[NavMetrics],
    recorder: RecordingProcess | None = None,
) -> NavSummary:
    """The run folder's series, streams and plots (the first seed's), metrics and report;
    ``recorder`` starts on the folder's files while the plots are drawn."""
    _write_series(first, run_dir)
    _write_sensor_streams(first, run_dir)
    summary = summarize_nav_seeds(per_seed)
    table = [{
        "scenario": sc.name, "seeds": len(per_seed),
        "output RMSE in the air (m)": summary.output_rmse_m,
        "output RMSE w/ vision (m)": summary.output_rmse_with_vision_m,
        "dropout end max (m)": summary.dropout_end_error_max_m,
        "recovery max (s)": summary.dropout_recovery_max_s,
        "hold max horiz (m)": summary.hold_max_horizontal_error_m,
        "attitude RMSE (deg)": summary.attitude_rmse_deg,
        "NEES (15)": summary.nees_mean,
    }]  # fmt: skip
    write_json(
        run_dir / "metrics.json",
        {
            "kind": "nav",
            "summary": summary.to_json(),
            "per_seed": [m.to_json() for m in per_seed],
            "table": table,
        },
    )
    if recorder is not None:  # what the recording reads is written: it goes on beside the plots
        recorder.start(run_dir, "nav")
    images = plot_nav_run(first, run_dir / "plots")
    write_report(
        run_dir / "report.html",
        title=f"{sc.name}: navigation flight ({len(per_seed)} seed(s))",
        sections=[
            ReportSection(
                heading="Metrics",
                tables=[
                    ReportTable(
                        "median over seeds (max for the worst-case rows)",
                        list(table[0]),
                        [list(table[0].values())],
                    )
                ],
            ),
            _refusal_section(summary),
            ReportSection(heading="Plots (first seed)", images=images),
            ReportSection(heading="Configuration", code=dump_config(sc)),
        ],
    )
    finish_run_folder(run_dir)
    return summary


def _refusal_section(summary: NavSummary) -> ReportSection:
    """The samples refused and the filter's resets (the fault scenarios' point)."""
    rows = [[what, n] for what, n in summary.refused.items()]
    return ReportSection(
        heading="Refused samples and resets",
        text="" if rows else "Every sample was fused or not due; the filter never reset.",
        tables=[ReportTable(f"total over {summary.seeds} seed(s)", ["what", "count"], rows)]
        if rows
        else [],
        code="\n".join(summary.filter_events),
    )


def _write_loop(r: NavRunResult, run_dir: Path) -> None:
    """With loop closure: each seed's counts (``loop_seed_<seed>.json``) and, with
    ``vio.save_map``, its map (``maps/seed_<seed>``)."""
    v = r.vio
    if v is None or v.loop is None:
        return
    write_json(run_dir / f"loop_seed_{r.seed}.json", v.loop)
    if v.loop_map is not None:
        from quadnav.io.loop_map import save_loop_map

        save_loop_map(run_dir / "maps" / f"seed_{r.seed}", v.loop_map)


def reports_in_flight(sc: NavScenario) -> bool:
    """Whether a flight is long enough to report its progress as it flies (the VIO on
    rendered images: minutes a flight)."""
    return sc.vio.enabled and sc.vio.source == "camera"


def run_nav_study(
    sc: NavScenario,
    *,
    runs_root: Path,
    progress: Progress | None = None,
    jobs: int = 1,
    mavlink: str | None = None,
    allow_remote: bool = False,
    rerun: RerunOptions | None = None,
) -> NavStudy:
    """Fly ``sc.seeds`` seeds; write the first seed's series and plots, every seed's metrics.
    With ``mavlink`` (a URL) the first seed's VIO odometry goes to an autopilot there (the
    seeds then fly in this process, one after the other). With ``rerun``, the finished folder's
    files are made into ``recording.rrd`` beside them (``quadnav[viz]``, checked before flying),
    streamed or opened as it asks."""
    if rerun:
        require_rerun("--rerun")
    recorder = RecordingProcess(rerun) if rerun else None  # imports rerun while the seeds fly
    if mavlink is not None and not sc.vio.enabled:
        raise ConfigError("--mavlink sends the VIO's odometry: this scenario has vio.enabled=false")
    if sc.vio.enabled and sc.vio.load_map is not None:  # a missing or bad map: before flying
        from quadnav.io.loop_map import load_loop_map

        load_loop_map(Path(sc.vio.load_map), option="vio.load_map")
    if reports_in_flight(sc):  # a camera slower than the rate asked: before flying
        flight_rig(sc.vio)
    run_dir = create_run_folder(runs_root, sc.name)
    write_text(run_dir / "config.yaml", dump_config(sc))
    seeds = [sc.seed + k for k in range(sc.seeds)]
    results: dict[int, NavMetrics] = {}
    firsts: list[NavRunResult] = []
    link = None if mavlink is None else MavlinkLink(mavlink, allow_remote=allow_remote)
    jobs = 1 if link is not None else jobs
    in_flight = reports_in_flight(sc) and (jobs <= 1 or len(seeds) <= 1)
    scale = 100 if in_flight else 1  # (in hundredths of seeds: progress within the flight)

    def collect(k: int, res: NavRunResult) -> None:
        _write_loop(res, run_dir)
        results[res.seed] = nav_metrics(res)
        append_jsonl(run_dir / "seeds.jsonl", results[res.seed].to_json())
        if k == 0:
            firsts.append(res)
        if progress:
            progress(scale * len(results), scale * len(seeds), f"seed {res.seed}")

    tasks = [(sc, seed) for seed in seeds]
    try:
        sink = None if link is None else OdometryLink(link)
        flown = progress if in_flight else None
        fn = _in_process(sc, flown, len(seeds), sink) if in_flight or sink else _one
        run_tasks(fn, tasks, collect, jobs=jobs)
    finally:
        if link is not None:
            link.close()
    first = firsts[0] if firsts else None
    assert first is not None
    per_seed = [results[s] for s in seeds]
    summary = _write_study(sc, run_dir, first, per_seed, recorder)
    if recorder is not None:  # from the folder's files, as quadnav view would
        recorder.record(run_dir, "nav")
    sent = dict(link.stats.sent) if link is not None else {}
    traffic = link.describe() if link is not None else ""
    return NavStudy(
        run_dir=run_dir,
        per_seed=per_seed,
        summary=summary,
        mavlink_sent=sent,
        mavlink_traffic=traffic,
    )
