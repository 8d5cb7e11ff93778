"""The replay of a PX4 log (``quadnav replay``) into a run folder: our navigation EKF over the
log's sensors, compared with PX4's own estimate and (SITL logs) the simulator's ground truth."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from quadnav.errors import IoError
from quadnav.estimation.horizon import SourceFusion
from quadnav.eval.report import ReportSection, ReportTable, write_report
from quadnav.experiments.replay import CHECK_NAMES, config_from_px4, replay
from quadnav.experiments.replay_compare import Comparison, compare, px4_innovations_as_ours
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.config import RawConfig, apply_override, dump_config
from quadnav.io.run_folder import create_run_folder, write_csv, write_json, write_text
from quadnav.io.trajectory_io import write_tum
from quadnav.io.ulog import read_ulog_trajectory
from quadnav.io.ulog_sensors import UlogSensors, read_ulog_sensors
from quadnav.units import ns_to_s

__all__ = ["ReplayMetrics", "replay_cell", "replay_log", "replay_overrides"]

#: What the question "what does PX4's estimate cover" is answered with, in ``metrics.json``.
COMPARED = (
    "each quantity only where PX4 flagged its estimate valid (horizontal: xy_valid, "
    "vertical: z_valid, attitude: vehicle_attitude logged); times in s from the log's start"
)


@dataclass(frozen=True, slots=True, kw_only=True)
class ReplayMetrics:
    """What a replay measured (``metrics.json``, by :meth:`as_json`) and where it wrote it."""

    log: Path
    duration_s: float
    replay_wall_s: float
    times_faster_than_flight: float
    datum_lla: tuple[float, float, float]
    counts: Mapping[str, Mapping[str, int]]  # per source, as the replay counts them
    notes: tuple[str, ...]
    events: tuple[str, ...]  # "12.345 s: message", from the log's start
    pairs: Mapping[str, Comparison]  # quadnav_vs_px4, quadnav_vs_truth, ...
    ratio_quadnav_to_px4_vs_truth: Mapping[str, float] | None  # SITL logs with PX4's estimate
    run_dir: Path
    compared: str = COMPARED

    def as_json(self) -> dict[str, object]:
        """``metrics.json``: the log, its counts, one entry per pair, what was compared."""
        out: dict[str, object] = {
            "log": str(self.log), "duration_s": self.duration_s,
            "replay_wall_s": self.replay_wall_s,
            "times_faster_than_flight": self.times_faster_than_flight,
            "datum_lla": self.datum_lla, "counts": self.counts, "notes": list(self.notes),
            "events": list(self.events),
        }  # fmt: skip
        out.update({k: dataclasses.asdict(v) for k, v in self.pairs.items()})
        if self.ratio_quadnav_to_px4_vs_truth is not None:
            out["ratio_quadnav_to_px4_vs_truth"] = self.ratio_quadnav_to_px4_vs_truth
        out["compared"] = self.compared
        return out


def replay_overrides(overrides: list[str]) -> RawConfig:
    """``--set name=value`` overrides of the EKF2 settings, as a mapping."""
    values: RawConfig = {}
    for o in overrides:
        apply_override(values, o)
    return values


def replay_log(
    log: Path,
    overrides: list[str],
    out: Path,
    progress: Callable[[int, int, str], None] | None = None,
) -> ReplayMetrics:
    """Replay ``log``'s sensors through the navigation EKF (EKF2's parameters from the log,
    ``overrides`` on top) into a run folder under ``out``; its metrics."""
    sensors = read_ulog_sensors(log)
    cfg = config_from_px4(sensors.params, replay_overrides(overrides))
    res = replay(sensors, cfg, progress=progress)
    ours = Trajectory(t_ns=res.t_ns, p_W_B=res.p, q_W_B_xyzw=res.q_xyzw, name="quadnav")
    run_dir = create_run_folder(out, f"replay_{log.stem}")
    write_text(run_dir / "config.yaml", dump_config(cfg))
    write_tum(run_dir / "quadnav.tum", ours)
    if res.gnss_checks is not None:  # why each fix was refused (1: that check failed)
        g = res.gnss_checks
        cols = {"t_ns": g.t_ns, "used": g.usable.astype(np.int64)}
        cols.update({name: (g.failed >> b) & 1 for b, name in enumerate(CHECK_NAMES)})
        write_csv(run_dir / "gnss_checks.csv", cols)
    trajs = {"quadnav": ours}
    notes = list(res.notes)
    try:
        px4 = read_ulog_trajectory(log)
        trajs["px4"] = Trajectory(
            t_ns=px4.t_ns, p_W_B=px4.p_W_B, q_W_B_xyzw=px4.q_W_B_xyzw, name="px4"
        )
        write_tum(run_dir / "px4.tum", trajs["px4"])
    except IoError as exc:
        notes.append(f"PX4 estimate not compared: {exc}")
    try:
        gt = read_ulog_trajectory(log, groundtruth=True)
        trajs["truth"] = Trajectory(
            t_ns=gt.t_ns, p_W_B=gt.p_W_B, q_W_B_xyzw=gt.q_W_B_xyzw, name="truth"
        )
        write_tum(run_dir / "truth.tum", trajs["truth"])
    except IoError:
        pass
    pairs = _comparisons(trajs, ours, sensors)
    metrics = ReplayMetrics(
        log=log,
        duration_s=sensors.duration_s,
        replay_wall_s=res.replay_wall_s,
        times_faster_than_flight=sensors.duration_s / max(res.replay_wall_s, 1e-9),
        datum_lla=res.datum_lla,
        counts=res.counts_json(),
        notes=tuple(notes),
        events=tuple(f"{ns_to_s(t - sensors.t_start_ns):.3f} s: {m}" for t, m in res.events),
        pairs=pairs,
        run_dir=run_dir,
        ratio_quadnav_to_px4_vs_truth=_ratios(pairs["quadnav_vs_truth"], pairs["px4_vs_truth"])
        if "quadnav_vs_truth" in pairs
        else None,
    )
    write_json(run_dir / "metrics.json", metrics.as_json())
    (run_dir / "plots").mkdir(exist_ok=True)
    t0 = sensors.t_start_ns
    images = [_plot_position(run_dir / "plots" / "position.png", trajs, t0)]
    images.append(_plot_innovations(run_dir / "plots" / "innovations.png", res.fusion, sensors))
    _write_report(run_dir, log, pairs, images, notes, COMPARED, res.replay_wall_s, sensors)
    return metrics


def _comparisons(
    trajs: dict[str, Trajectory], ours: Trajectory, sensors: UlogSensors
) -> dict[str, Comparison]:
    t0, valid = sensors.t_start_ns, sensors.px4_validity
    pairs: dict[str, Comparison] = {}
    if "px4" in trajs:
        pairs["quadnav_vs_px4"] = compare(trajs["px4"], ours, t0_ns=t0, validity=valid)
    if "truth" in trajs:
        if "px4" in trajs:  # on the spans PX4 called valid, so the two are compared alike
            pairs["quadnav_vs_truth"] = compare(trajs["truth"], ours, t0_ns=t0, validity=valid)
            pairs["px4_vs_truth"] = compare(trajs["truth"], trajs["px4"], t0_ns=t0, validity=valid)
        pairs["quadnav_vs_truth_everywhere"] = compare(
            trajs["truth"], ours, t0_ns=t0, validity=None
        )
    return pairs


def _write_report(
    run_dir: Path,
    log: Path,
    pairs: dict[str, Comparison],
    images: list[Path],
    notes: list[str],
    compared: str,
    wall_s: float,
    sensors: UlogSensors,
) -> None:
    cols = (
        "horizontal_rms_m",
        "vertical_rms_m",
        "horizontal_max_m",
        "vertical_max_m",
        "tilt_rms_deg",
        "yaw_rms_deg",
    )
    rows = [[k, *(replay_cell(getattr(v, m), 3) for m in cols)] for k, v in pairs.items()]
    spans = "\n".join(
        f"{k}: horizontal {_fmt(v.horizontal_spans_s)}; vertical {_fmt(v.vertical_spans_s)}; attitude {_fmt(v.attitude_spans_s)}; "
        f"not compared: {', '.join(f'{q} {a:.2f}-{b:.2f} s' for q, a, b in v.not_compared_s) or 'none'}"
        for k, v in pairs.items()
    )
    header = [
        "pair",
        "horizontal RMS (m)",
        "vertical RMS (m)",
        "horizontal max (m)",
        "vertical max (m)",
        "tilt RMS (deg)",
        "yaw RMS (deg)",
    ]
    config = (run_dir / "config.yaml").read_text()
    write_report(
        run_dir / "report.html",
        title=f"replay of {log.name}",
        sections=[
            ReportSection(
                "Comparison",
                text=f"{sensors.duration_s:.1f} s of flight replayed in {wall_s:.2f} s. {compared}.",
                tables=[ReportTable("position and attitude differences", header, rows)],
            ),
            ReportSection("Compared spans (s from the log's start)", text=spans),
            ReportSection("Plots", images=images),
            ReportSection("Notes", text="\n".join(notes) or "nothing skipped"),
            ReportSection("Configuration", code=config),
        ],
    )


def replay_cell(value: float, digits: int) -> str:
    """A table cell: the number, or why there is none (PX4 never called that estimate valid)."""
    return f"{value:.{digits}f}" if math.isfinite(value) else "not compared"


def _ratios(ours: Comparison, px4: Comparison) -> dict[str, float]:
    keys = ("horizontal_rms_m", "vertical_rms_m", "tilt_rms_deg", "yaw_rms_deg", "attitude_rms_deg")
    return {
        k: getattr(ours, k) / getattr(px4, k) if getattr(px4, k) > 0 else float("nan") for k in keys
    }


def _fmt(spans: tuple[tuple[float, float], ...]) -> str:
    return ", ".join(f"{a:.2f}-{b:.2f}" for a, b in spans) or "none"


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _plot_position(path: Path, trajs: dict[str, Trajectory], t0_ns: int) -> Path:
    """East, north and up of every trajectory against seconds from the log's start."""
    plt = _pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(12, 8), sharex=True, constrained_layout=True)
    for name, tr in trajs.items():
        for k, ax in enumerate(axes):
            ax.plot(
                (tr.t_ns - t0_ns) * 1e-9,
                tr.p_W_B[:, k],
                "--" if name == "truth" else "-",
                lw=1.2,
                label=name,
            )
    for k, ax in enumerate(axes):
        ax.set_ylabel(f"{('east', 'north', 'up')[k]} (m)")
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8, loc="best")
    axes[-1].set_xlabel("t (s from the log's start)")
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _plot_innovations(path: Path, ours: Mapping[str, SourceFusion], s: UlogSensors) -> Path:
    """Our innovations beside PX4's, component by component, in one convention (ENU, the
    measurement minus the prediction) and one time axis."""
    plt = _pyplot()
    pairs = px4_innovations_as_ours(s.px4_innovations, s.px4_validity, s.t_start_ns)
    fig, axes = plt.subplots(
        max(len(pairs), 1),
        1,
        figsize=(12, 3 * max(len(pairs), 1)),
        sharex=True,
        squeeze=False,
        constrained_layout=True,
    )
    for ax, p in zip(axes[:, 0], pairs, strict=False):
        f = ours.get(p.source)
        if f is not None and len(f):
            t_s = (f.t_obs_ns - s.t_start_ns) * 1e-9
            ax.plot(t_s, f.innovation[:, p.column], ".", ms=2, label="quadnav")
        ax.plot(p.px4_t_s, p.px4_m, ".", ms=2, color="tab:orange", label="PX4")
        ax.set_title(p.label, fontsize=9)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    axes[-1, 0].set_xlabel("t (s from the log's start)")
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
