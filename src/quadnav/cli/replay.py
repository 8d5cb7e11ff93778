"""``quadnav replay LOG.ulg``: our navigation EKF over a PX4 log's sensors, next to PX4's own
estimate and (SITL logs) the simulator's ground truth."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.table import Table

from quadnav.cli.common import console, err_console, handle_errors, progress_bar
from quadnav.cli.planar import OutOpt, SetOpt
from quadnav.errors import IoError
from quadnav.eval.associate import associate
from quadnav.eval.metrics import ape
from quadnav.eval.plots import plot_xyz
from quadnav.eval.report import ReportSection, ReportTable, write_report
from quadnav.experiments.replay import config_from_px4, replay
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.config import apply_override, dump_config
from quadnav.io.run_folder import create_run_folder, write_json
from quadnav.io.trajectory_io import write_tum
from quadnav.io.ulog import read_ulog_trajectory
from quadnav.io.ulog_sensors import read_ulog_sensors

__all__ = ["compare", "replay_command", "replay_log"]


def compare(ref: Trajectory, est: Trajectory) -> dict[str, float]:
    """Horizontal/vertical RMS and max difference of ``est`` from ``ref`` (interpolated at
    ``est``'s times inside ``ref``'s span), and the attitude RMS difference (deg)."""
    r, e = associate(ref, est, t_max_diff_s=0.5, interpolate=True)
    d = e.p_W_B - r.p_W_B
    h = np.linalg.norm(d[:, 0:2], axis=1)
    att = np.degrees(ape(r, e, "rot"))
    return {"n": len(r), "horizontal_rms_m": float(np.sqrt(np.mean(h**2))), "horizontal_max_m": float(h.max()),
            "vertical_rms_m": float(np.sqrt(np.mean(d[:, 2] ** 2))), "vertical_max_m": float(np.abs(d[:, 2]).max()),
            "position_rms_m": float(np.sqrt(np.mean(np.sum(d**2, axis=1)))), "attitude_rms_deg": float(np.sqrt(np.mean(att**2))),
            "t_of_max_vertical_s": float(r.t_ns[int(np.argmax(np.abs(d[:, 2])))] * 1e-9)}  # fmt: skip


def replay_log(log: Path, overrides: list[str], out: Path, progress: Any = None) -> dict[str, Any]:
    sensors = read_ulog_sensors(log)
    values: dict[str, Any] = {}
    for o in overrides:
        apply_override(values, o)
    cfg = config_from_px4(sensors.params, values)
    res = replay(sensors, cfg, progress=progress)
    ours = Trajectory(t_ns=res.t_ns, p_W_B=res.p, q_W_B_xyzw=res.q_xyzw, name="quadnav")
    run_dir = create_run_folder(out, f"replay_{log.stem}")
    (run_dir / "config.yaml").write_text(dump_config(cfg))
    write_tum(run_dir / "quadnav.tum", ours)
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
    metrics: dict[str, Any] = {"log": str(log), "duration_s": sensors.duration_s, "replay_wall_s": res.replay_wall_s,
                               "times_faster_than_flight": sensors.duration_s / max(res.replay_wall_s, 1e-9),
                               "datum_lla": res.datum_lla, "counts": res.counts, "notes": notes,
                               "events": [f"{t * 1e-9:.3f} s: {m}" for t, m in res.events]}  # fmt: skip
    if "px4" in trajs:
        metrics["quadnav_vs_px4"] = compare(trajs["px4"], ours)
    if "truth" in trajs:
        metrics["quadnav_vs_truth"] = compare(trajs["truth"], ours)
        if "px4" in trajs:
            metrics["px4_vs_truth"] = compare(trajs["truth"], trajs["px4"])
    write_json(run_dir / "metrics.json", metrics)
    (run_dir / "plots").mkdir(exist_ok=True)
    ref = trajs.get("truth", trajs.get("px4", ours))
    images = [run_dir / "plots" / "position.png"]
    plot_xyz(ref, [t for k, t in trajs.items() if t is not ref], images[0])
    images.append(
        _plot_innovations(
            run_dir / "plots" / "innovations.png", res.fusion, sensors.px4_innovations
        )
    )
    rows = [[k, *(f"{v[m]:.3f}" for m in ("horizontal_rms_m", "vertical_rms_m", "horizontal_max_m", "vertical_max_m", "attitude_rms_deg"))]
            for k, v in metrics.items() if isinstance(v, dict) and "horizontal_rms_m" in v]  # fmt: skip
    write_report(run_dir / "report.html", title=f"replay of {log.name}", sections=[
        ReportSection("Comparison", text=f"{sensors.duration_s:.1f} s of flight replayed in {res.replay_wall_s:.2f} s.",
                      tables=[ReportTable("position and attitude differences", ["pair", "horizontal RMS (m)", "vertical RMS (m)", "horizontal max (m)", "vertical max (m)", "attitude RMS (deg)"], rows)]),
        ReportSection("Plots", images=images),
        ReportSection("Notes", text="\n".join(notes) or "nothing skipped"),
        ReportSection("Configuration", code=dump_config(cfg)),
    ])  # fmt: skip
    metrics["run_dir"] = str(run_dir)
    return metrics


def _plot_innovations(
    path: Path, ours: dict[str, dict[str, np.ndarray]], px4: dict[str, np.ndarray]
) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pairs = [
        ("gps", 0, "gps_hpos[0]", "GNSS north/east innovation (m)"),
        ("baro", 0, "baro_vpos", "barometer innovation (m)"),
    ]
    fig, axes = plt.subplots(
        len(pairs), 2, figsize=(12, 3 * len(pairs)), squeeze=False, constrained_layout=True
    )
    for row, (src, k, key, label) in zip(axes, pairs, strict=True):
        f = ours.get(src)
        if f is not None and len(f["t_obs_ns"]):
            row[0].plot(f["t_obs_ns"] * 1e-9, f["innovation"][:, k], ".", ms=2)
        row[0].set_title(f"quadnav: {label}", fontsize=9)
        if key in px4:
            sign = -1.0 if key == "baro_vpos" else 1.0  # PX4 logs down-positive heights
            row[1].plot(px4["t_ns"] * 1e-9, sign * px4[key], ".", ms=2, color="tab:orange")
        row[1].set_title(f"PX4: {label}", fontsize=9)
        for ax in row:
            ax.grid(True, alpha=0.3)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


@handle_errors
def replay_command(
    log: Annotated[Path, typer.Argument(help="PX4 ULog file")],
    set_: SetOpt = None,
    out: OutOpt = Path("runs"),
) -> None:
    """Replay a PX4 log's sensors through quadnav's navigation EKF (started from the log's EKF2
    parameters; override with --set gps_delay_s=0.2 ...) and compare with PX4's estimate."""
    with progress_bar("replay") as update:
        m = replay_log(log, list(set_ or []), out, update)
    table = Table(
        title=f"replay of {log.name}: {m['duration_s']:.1f} s in {m['replay_wall_s']:.2f} s ({m['times_faster_than_flight']:.0f}x)"
    )
    for c in ("pair", "horizontal RMS (m)", "vertical RMS (m)", "attitude RMS (deg)"):
        table.add_column(c, justify="right" if c != "pair" else "left")
    for k in ("quadnav_vs_px4", "quadnav_vs_truth", "px4_vs_truth"):
        if k in m:
            v = m[k]
            table.add_row(
                k.replace("_", " "),
                f"{v['horizontal_rms_m']:.3f}",
                f"{v['vertical_rms_m']:.3f}",
                f"{v['attitude_rms_deg']:.2f}",
            )
    console.print(table)
    for n in m["notes"]:
        err_console.print(f"note: {n}", highlight=False)
    console.print(m["run_dir"], soft_wrap=True, highlight=False)
