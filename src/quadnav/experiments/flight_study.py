"""Closed-loop flights (``quadnav sim``): their metrics, plots and run folders."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Rectangle
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.eval.metrics import settling_time_s
from quadnav.eval.na import Metric, na, rms_or_na
from quadnav.eval.report import ReportSection, ReportTable, write_report
from quadnav.experiments.flight import FlightEvents, FlightRun
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.config import dump_config
from quadnav.io.run_folder import (
    create_run_folder,
    finish_run_folder,
    write_csv,
    write_json,
    write_text,
)
from quadnav.io.trajectory_io import write_tum
from quadnav.units import s_to_ns

__all__ = ["FlightMetrics", "TrackingMetrics", "flight_metrics", "plot_flight", "write_flight_run"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackingMetrics:
    """Against the time reference (scenarios that have one)."""

    settling_time_s: Metric
    tracking_rmse_m: Metric
    tracking_rmse_whole_run_m: Metric
    final_error_m: float
    overshoot_pct: dict[str, float]  # per axis that had a step


@dataclass(frozen=True, slots=True, kw_only=True)
class FlightMetrics:
    """One flight's figures: tracking (None without a time reference), control effort,
    saturation, clearance, tilt, speed, and thesis 003's events."""

    scenario: str
    duration_s: float
    tracking: TrackingMetrics | None
    peak_thrust_n: float
    peak_torque: float
    torque_unit: str
    saturation_time_s: float
    rotor_speed_range_rad_s: tuple[float, float] | None
    min_obstacle_distance_m: float | None
    max_tilt_deg: float
    sim_seconds_per_wall_second: float
    events: FlightEvents

    def rows(self) -> list[tuple[str, object]]:
        """(name, value) of every figure there is, in print order (``None`` left out)."""
        out: list[tuple[str, object]] = [
            ("scenario", self.scenario),
            ("duration_s", self.duration_s),
        ]
        if self.tracking is not None:
            out += [(f.name, getattr(self.tracking, f.name)) for f in fields(self.tracking)]
        for f in fields(self):
            if f.name not in ("scenario", "duration_s", "tracking", "events"):
                out.append((f.name, getattr(self, f.name)))
        return [(k, v) for k, v in out if v is not None]

    def to_json(self) -> dict[str, object]:
        """The ``metrics.json`` form (the events as a mapping)."""
        return {**dict(self.rows()), "events": dict(self.events.items())}


def _tracking(run: FlightRun) -> TrackingMetrics | None:
    cfg, t = run.config, run.t_s
    if not np.isfinite(run.ref_p).all():
        return None
    e = run.p - run.ref_p
    err = np.linalg.norm(e, axis=1)
    settle = settling_time_s(t, err, cfg.settle_band_m)
    over = {}
    for k, axis in enumerate("xyz"):
        if abs(e[0, k]) > 0.1:  # a step on this axis: how far past the reference it went
            over[axis] = float(max(0.0, np.max(-e[:, k] * np.sign(e[0, k]))) / abs(e[0, k]) * 100.0)
    return TrackingMetrics(
        settling_time_s=settle
        if math.isfinite(settle)
        else na(f"not settled within settle_band_m ({cfg.settle_band_m:g} m) by the end"),
        tracking_rmse_m=rms_or_na(
            err[t >= cfg.tracking_start_s],
            f"no samples after tracking_start_s ({cfg.tracking_start_s:g} s) in a "
            f"{cfg.duration_s:g} s flight",
        ),
        tracking_rmse_whole_run_m=rms_or_na(err, "no samples"),
        final_error_m=float(err[-1]),
        overshoot_pct=over,
    )


def flight_metrics(run: FlightRun) -> FlightMetrics:
    """Settling time, overshoot, tracking RMSE, peak control effort, saturation time, clearance."""
    cfg = run.config
    t = run.t_s
    dt_log = float(t[1] - t[0]) if len(t) > 1 else cfg.dt_s
    rotors = None
    if np.isfinite(run.rotor_rad_s).any():
        rotors = (float(np.nanmin(run.rotor_rad_s)), float(np.nanmax(run.rotor_rad_s)))
    clearance = float(np.min(run.obstacle_distance_m))
    return FlightMetrics(
        scenario=cfg.name,
        duration_s=cfg.duration_s,
        tracking=_tracking(run),
        peak_thrust_n=float(np.nanmax(np.abs(run.thrust_n))),
        peak_torque=float(np.nanmax(np.abs(run.torque))),
        torque_unit="rad/s^2 (tau~ of eq. A.8)" if cfg.vehicle == "euler_lagrange" else "N m",
        saturation_time_s=float(run.saturated.sum() * dt_log),
        rotor_speed_range_rad_s=rotors,
        min_obstacle_distance_m=clearance if math.isfinite(clearance) else None,
        max_tilt_deg=float(np.degrees(np.max(np.abs(run.euler_rpy[:, 0:2])))),
        sim_seconds_per_wall_second=cfg.duration_s / run.wall_time_s
        if run.wall_time_s > 0
        else math.inf,
        events=run.events,
    )


def plot_flight(run: FlightRun, folder: Path) -> list[Path]:
    """Positions, Euler angles and control signals against time (thesis figures 5.1-5.13),
    and a top view with the obstacles."""
    t = run.t_s
    paths = []
    fig, axes = plt.subplots(3, 1, figsize=(11, 8), sharex=True, constrained_layout=True)
    for k, ax in enumerate(axes):
        ax.plot(t, run.p[:, k], label="vehicle")
        if np.isfinite(run.ref_p).all():
            ax.plot(t, run.ref_p[:, k], "--", label="reference")
        ax.set_ylabel(f"{'xyz'[k]} (m)")
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("t (s)")
    fig.suptitle(f"{run.config.name}: position")
    paths.append(folder / "positions.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)

    fig, axes = plt.subplots(3, 1, figsize=(11, 8), sharex=True, constrained_layout=True)
    for k, (ax, name) in enumerate(zip(axes, ("roll phi", "pitch theta", "yaw psi"), strict=True)):
        ax.plot(t, np.degrees(run.euler_rpy[:, k]))
        ax.set_ylabel(f"{name} (deg)")
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("t (s)")
    fig.suptitle(f"{run.config.name}: Euler angles")
    paths.append(folder / "euler.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)

    fig, axes = plt.subplots(4, 1, figsize=(11, 9), sharex=True, constrained_layout=True)
    unit = "rad/s^2" if run.config.vehicle == "euler_lagrange" else "N m"
    axes[0].plot(t, run.thrust_n)
    axes[0].set_ylabel("u (N)")
    for k, name in enumerate(("tau_phi", "tau_theta", "tau_psi")):
        axes[k + 1].plot(t, run.torque[:, k])
        axes[k + 1].set_ylabel(f"{name} ({unit})")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        if run.saturated.any():
            ax.fill_between(
                t,
                0,
                1,
                where=run.saturated,
                transform=ax.get_xaxis_transform(),
                color="tab:red",
                alpha=0.12,
            )
    axes[-1].set_xlabel("t (s)")
    fig.suptitle(f"{run.config.name}: control signals (red: saturated)")
    paths.append(folder / "controls.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)

    paths.append(_plot_top_view(run, folder))
    return paths


def _top_view_axes(ax: Any) -> None:
    """A top view's axes: equal scales, x and y in metres, grid, legend."""
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)


def _plot_top_view(run: FlightRun, folder: Path) -> Path:
    """The path from above with the reference, the obstacles and the waypoints."""
    fig, ax = plt.subplots(figsize=(8, 7), constrained_layout=True)
    ax.plot(run.p[:, 0], run.p[:, 1], label="vehicle")
    if np.isfinite(run.ref_p).all():
        ax.plot(run.ref_p[:, 0], run.ref_p[:, 1], "--", label="reference")
    for b in run.config.world:
        ax.add_patch(
            Rectangle(
                (b.min_m[0], b.min_m[1]),
                b.max_m[0] - b.min_m[0],
                b.max_m[1] - b.min_m[1],
                color="0.6",
                alpha=0.6,
                label=b.name,
            )
        )
    if run.config.controller == "waypoint_follower":
        pts = np.asarray(run.config.trajectory.points_m)
        ax.plot(pts[:, 0], pts[:, 1], "k^", label="waypoints")
    _top_view_axes(ax)
    ax.set_title(f"{run.config.name}: top view")
    fig.savefig(folder / "top_view.png", dpi=100)
    plt.close(fig)
    return folder / "top_view.png"


def _write_link(run: FlightRun, run_dir: Path) -> Path:
    """``link.csv`` and ``plots/link.png``: the position sent over the serial link (the SLAM's
    or the true one) against the flown one and the reference."""
    link = run.link
    assert link is not None
    cols: dict[str, NDArray[Any]] = {
        "t_ns": np.array([s_to_ns(float(t)) for t in link.t_s], np.int64)
    }
    for name, arr in (("sent", link.p_sent), ("true", link.p_true)):
        for k, a in enumerate("xyz"):
            cols[f"{name}_{a}_m"] = arr[:, k]
    write_csv(run_dir / "link.csv", cols)
    fig, axes = plt.subplots(2, 2, figsize=(12, 8), constrained_layout=True)
    label = "SLAM (sent)" if link.source == "slam" else "sent"
    for k, ax in enumerate((axes[0, 0], axes[0, 1], axes[1, 0])):
        ax.plot(run.t_s, run.p[:, k], label="true")
        ax.plot(link.t_s, link.p_sent[:, k], ".", ms=3, label=label)
        if np.isfinite(run.ref_p).all():
            ax.plot(run.t_s, run.ref_p[:, k], "--", label="reference")
        ax.set_ylabel(f"{'xyz'[k]} (m)")
        ax.set_xlabel("t (s)")
        ax.grid(True, alpha=0.3)
    ax = axes[1, 1]
    ax.plot(run.p[:, 0], run.p[:, 1], label="true")
    ax.plot(link.p_sent[:, 0], link.p_sent[:, 1], ".", ms=3, label=label)
    if np.isfinite(run.ref_p).all():
        ax.plot(run.ref_p[:, 0], run.ref_p[:, 1], "--", label="reference")
    _top_view_axes(ax)
    fig.suptitle(f"{run.config.name}: {label} against true and reference")
    path = run_dir / "plots" / "link.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def write_flight_run(run: FlightRun, *, runs_root: Path) -> tuple[Path, FlightMetrics]:
    """A run folder: config, states and controls CSV, TUM trajectory, metrics, plots, report."""
    cfg = run.config
    run_dir = create_run_folder(runs_root, cfg.name)
    write_text(run_dir / "config.yaml", dump_config(cfg))
    t_ns = np.array([s_to_ns(t) for t in run.t_s], dtype=np.int64)
    cols: dict[str, NDArray[Any]] = {"t_ns": t_ns}
    for k, a in enumerate("xyz"):
        cols[f"{a}_m"] = run.p[:, k]
    for k, a in enumerate("xyz"):
        cols[f"v{a}_m_s"] = run.v[:, k]
    for k, a in enumerate(("roll", "pitch", "yaw")):
        cols[f"{a}_rad"] = run.euler_rpy[:, k]
    for k, a in enumerate("xyz"):
        cols[f"ref_{a}_m"] = run.ref_p[:, k]
    write_csv(run_dir / "states.csv", cols)
    ctrl: dict[str, NDArray[Any]] = {"t_ns": t_ns, "thrust_n": run.thrust_n}
    for k, a in enumerate(("tau_phi", "tau_theta", "tau_psi")):
        ctrl[a] = run.torque[:, k]
    for k in range(4):
        ctrl[f"rotor{k + 1}_rad_s"] = run.rotor_rad_s[:, k]
    ctrl["saturated"] = run.saturated
    write_csv(run_dir / "controls.csv", ctrl)
    q = Rotation.from_euler("ZYX", run.euler_rpy[:, ::-1]).as_quat()
    write_tum(
        run_dir / "trajectory.tum", Trajectory(t_ns=t_ns, p_W_B=run.p, q_W_B_xyzw=q, name=cfg.name)
    )
    metrics = flight_metrics(run)
    images = plot_flight(run, run_dir / "plots")
    no_ref = na("no reference trajectory")
    tr = metrics.tracking
    row: dict[str, object] = {
        "scenario": cfg.name,
        "tracking RMSE (m)": no_ref if tr is None else tr.tracking_rmse_m,
        "settling (s)": no_ref if tr is None else tr.settling_time_s,
        "peak thrust (N)": metrics.peak_thrust_n,
        "saturated (s)": metrics.saturation_time_s,
        "min clearance (m)": metrics.min_obstacle_distance_m
        if metrics.min_obstacle_distance_m is not None
        else na("no obstacle"),
    }
    extra: dict[str, object] = {}
    if run.link is not None:
        extra["link"] = run.link.metrics()
        images.append(_write_link(run, run_dir))
        row["sent position RMSE (m)"] = extra["link"]["sent_position_rmse_m"]  # type: ignore[index]
    write_json(
        run_dir / "metrics.json", {"kind": "sim", **metrics.to_json(), **extra, "table": [row]}
    )
    write_report(
        run_dir / "report.html",
        title=f"Flight: {cfg.name}",
        sections=[
            ReportSection(
                heading="Metrics",
                tables=[ReportTable("", list(row), [list(row.values())])],
                text="events: " + ", ".join(f"{k} {v}" for k, v in run.events.items()),
            ),
            ReportSection(heading="Plots", images=images),
            ReportSection(heading="Configuration", code=dump_config(cfg)),
        ],
    )
    finish_run_folder(run_dir)
    return run_dir, metrics
