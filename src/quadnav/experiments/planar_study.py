"""The planar study (thesis 000, figures 2.3-2.5): its seeds run, their metrics, plots and run folder."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import EvalError
from quadnav.eval.metrics import ape, error_stats, nees
from quadnav.eval.na import Metric, na
from quadnav.eval.planar import (
    PlanarMetrics,
    PlanarSummary,
    planar_trajectory,
    plot_monte_carlo,
    summarize_seeds,
)
from quadnav.eval.report import ReportSection, ReportTable, write_report
from quadnav.experiments.planar import ExperimentName, PlanarConfig, PlanarRun, run_planar
from quadnav.experiments.seeds import run_tasks
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.config import dump_config
from quadnav.io.run_folder import (
    append_jsonl,
    create_run_folder,
    finish_run_folder,
    write_csv,
    write_json,
    write_text,
)
from quadnav.io.trajectory_io import write_tum

__all__ = [
    "PlanarStudy",
    "planar_metrics",
    "planar_table",
    "plot_planar_run",
    "run_planar_study",
]

FloatArray = NDArray[np.float64]
Progress = Callable[[int, int, str], None]


def _wrap(a: FloatArray) -> FloatArray:
    return np.asarray((a + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


def _delayed_errors(run: PlanarRun, rows: NDArray[np.int64]) -> FloatArray:
    di = run.delayed_index[rows]
    ref = np.column_stack([run.truth_p[di], run.truth_v[di], run.truth_theta[di]])
    err = run.delayed_x[rows] - ref
    err[:, 4] = _wrap(err[:, 4])
    return err


def planar_metrics(run: PlanarRun) -> PlanarMetrics:
    """Position RMSE of each estimate against the truth at its own horizon, the floor, NEES.

    * delayed: the filter's estimate against the truth at the delayed horizon, over the steps
      after the horizon started moving;
    * output and floor: against the truth now, over every step after the start;
    * NEES of the 5-state delayed estimate, averaged over the steps after the first fused fix
      (over every step when nothing was fused).
    """
    rows = np.arange(1, len(run.t_ns))
    rows_d = rows[run.t_delayed_ns[rows] > run.t_ns[0]]
    di = run.delayed_index[rows_d]
    t_d = run.t_delayed_ns[rows_d]

    def rmse(ref: Trajectory, est: Trajectory) -> Metric:
        if len(ref.t_ns) == 0:
            return na("run not longer than the delay: the delayed horizon never moved")
        return float(error_stats(ape(ref, est, "trans"))["rmse"])

    truth_now = planar_trajectory(run.t_ns[rows], run.truth_p[rows], run.truth_theta[rows])
    rmse_d = rmse(
        planar_trajectory(t_d, run.truth_p[di], run.truth_theta[di]),
        planar_trajectory(t_d, run.delayed_x[rows_d, 0:2], run.delayed_x[rows_d, 4]),
    )
    rmse_o = rmse(
        truth_now, planar_trajectory(run.t_ns[rows], run.output_p[rows], run.output_theta[rows])
    )
    rmse_f = rmse(
        truth_now, planar_trajectory(run.t_ns[rows], run.floor_p[rows], run.floor_theta[rows])
    )
    fused = run.fusion_t_obs_ns[run.fusion_accepted]
    # After the first fused fix; with no fix at all (IMU only), over every step, which tests
    # the consistency of the covariance propagation alone.
    m = rows_d[run.t_delayed_ns[rows_d] >= fused.min()] if len(fused) else rows_d
    nees_mean: Metric = na("no delayed estimate after the first fused fix")
    if len(m):
        nees_mean = float(nees(_delayed_errors(run, m), run.delayed_P[m]).mean())
    ratio: Metric = na("no floor to compare with")
    if isinstance(rmse_o, float) and isinstance(rmse_f, float) and rmse_f > 0:
        ratio = rmse_o / rmse_f
    return PlanarMetrics(
        seed=run.seed,
        rmse_delayed_m=rmse_d,
        rmse_output_m=rmse_o,
        rmse_floor_m=rmse_f,
        output_over_floor=ratio,
        nees_mean=nees_mean,
        nees_steps=len(m),
        gps_received=run.gps_received,
        gps_fused=run.gps_fused,
        gps_rejected_gate=run.gps_rejected_gate,
        gps_rejected_too_old=run.gps_rejected_too_old,
        gps_pending_at_end=run.gps_pending,
        imu_buffer_length=run.buffer_length,
    )


_TITLES = {
    "no_update": "No measurement update (IMU only)",
    "naive": "Delayed GPS fused as if current",
    "handled": "Delays handled: delayed horizon + output predictor",
}


def plot_planar_run(run: PlanarRun, path: Path) -> None:
    """One figure per experiment: x(t), z(t), the trajectory, theta(t), errors with +-1 sigma."""
    t = run.t_ns * 1e-9
    td = run.t_delayed_ns * 1e-9
    started = run.t_delayed_ns > run.t_ns[0]
    handled = run.buffer_length > 1
    fig, axes = plt.subplots(2, 3, figsize=(16, 9), constrained_layout=True)
    fig.suptitle(f"{_TITLES[run.experiment]} (seed {run.seed})")
    for k, (ax, label) in enumerate(zip(axes[0, :2], ("x", "z"), strict=True)):
        ax.plot(t, run.truth_p[:, k], "--", color="tab:blue", label="truth")
        ekf_label = "EKF (delayed horizon)" if handled else "EKF"
        ax.plot(td[started], run.delayed_x[started, k], color="tab:orange", label=ekf_label)
        if handled:
            ax.plot(t, run.output_p[:, k], color="tab:green", label="output predictor")
        if len(run.gps_t_valid_ns):
            ax.plot(
                run.gps_t_valid_ns * 1e-9,
                run.gps_p[:, k],
                "x",
                color="tab:red",
                ms=4,
                label="GPS (time of validity)",
            )
        ax.set_xlabel("t (s)")
        ax.set_ylabel(f"{label} (m)")
        ax.set_title(f"Position {label}")
        ax.legend(fontsize=8)
    ax = axes[0, 2]
    ax.plot(run.truth_p[:, 0], run.truth_p[:, 1], "--", color="tab:blue", label="truth")
    ax.plot(run.delayed_x[started, 0], run.delayed_x[started, 1], color="tab:orange", label="EKF")
    if handled:
        ax.plot(run.output_p[:, 0], run.output_p[:, 1], color="tab:green", label="output predictor")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_title("Trajectory")
    ax.legend(fontsize=8)
    ax = axes[1, 0]
    ax.plot(t, np.degrees(run.truth_theta), "--", color="tab:blue", label="truth")
    ax.plot(td[started], np.degrees(run.delayed_x[started, 4]), color="tab:orange", label="EKF")
    if handled:
        ax.plot(t, np.degrees(run.output_theta), color="tab:green", label="output predictor")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("theta (deg)")
    ax.set_title("Pitch")
    ax.legend(fontsize=8)
    rows = np.flatnonzero(started)
    err = _delayed_errors(run, rows) if len(rows) else np.zeros((0, 5))
    for k, (ax, label) in enumerate(zip(axes[1, 1:], ("x", "z"), strict=True)):
        sigma = np.sqrt(run.delayed_P[rows, k, k])
        ax.fill_between(
            td[rows], -sigma, sigma, color="tab:orange", alpha=0.25, label="EKF +-1 sigma"
        )
        ax.plot(td[rows], err[:, k], color="tab:orange", label="EKF - delayed truth")
        if handled:
            ax.plot(
                t,
                run.output_p[:, k] - run.truth_p[:, k],
                color="tab:green",
                lw=0.8,
                label="output - truth",
            )
            ax.plot(
                t,
                run.floor_p[:, k] - run.truth_p[:, k],
                color="black",
                lw=0.8,
                ls=":",
                label="floor - truth",
            )
        ax.set_xlabel("t (s)")
        ax.set_ylabel("error (m)")
        ax.set_title(f"Position error {label}")
        ax.legend(fontsize=8)
        if handled and len(rows):
            lim = 4.0 * max(float(np.max(sigma)), float(np.max(np.abs(err[:, k]))), 1e-3)
            lim = max(lim, 1.2 * float(np.max(np.abs(run.output_p[:, k] - run.truth_p[:, k]))))
            ax.set_ylim(-lim, lim)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _state_columns(
    t_ns: NDArray[np.int64], p: FloatArray, v: FloatArray, theta: FloatArray
) -> dict[str, NDArray[Any]]:
    return {
        "t_ns": t_ns,
        "x_m": p[:, 0],
        "z_m": p[:, 1],
        "vx_m_s": v[:, 0],
        "vz_m_s": v[:, 1],
        "theta_rad": theta,
    }


def _write_run_series(run: PlanarRun, folder: Path) -> None:
    t = run.t_ns
    write_csv(folder / "truth.csv", _state_columns(t, run.truth_p, run.truth_v, run.truth_theta))
    write_csv(
        folder / "output.csv", _state_columns(t, run.output_p, run.output_v, run.output_theta)
    )
    write_csv(folder / "floor.csv", _state_columns(t, run.floor_p, run.floor_v, run.floor_theta))
    # One row per delayed-horizon time (it waits at t0 until the IMU buffer fills).
    moved = np.flatnonzero(np.diff(run.t_delayed_ns, prepend=run.t_delayed_ns[0] - 1) != 0)
    cols: dict[str, NDArray[Any]] = {"t_ns": run.t_delayed_ns[moved], "t_now_ns": t[moved]}
    for k, name in enumerate(("x_m", "z_m", "vx_m_s", "vz_m_s", "theta_rad")):
        cols[name] = run.delayed_x[moved, k]
    for k, name in enumerate(("x", "z", "vx", "vz", "theta")):
        cols[f"var_{name}"] = run.delayed_P[moved, k, k]
    write_csv(folder / "delayed.csv", cols)
    write_csv(
        folder / "gps.csv",
        {
            "t_ns": run.gps_t_valid_ns,
            "t_arrival_ns": run.gps_t_arrival_ns,
            "x_m": run.gps_p[:, 0],
            "z_m": run.gps_p[:, 1],
        },
    )
    write_csv(
        folder / "innovations.csv",
        {
            "t_ns": run.fusion_t_obs_ns,
            "t_fused_ns": run.fusion_t_fused_ns,
            "innov_x_m": run.fusion_innovation[:, 0],
            "innov_z_m": run.fusion_innovation[:, 1],
            "nis": run.fusion_nis,
            "test_ratio": run.fusion_test_ratio,
            "accepted": run.fusion_accepted,
        },
    )

    write_tum(folder / "truth.tum", planar_trajectory(t, run.truth_p, run.truth_theta, "truth"))
    write_tum(folder / "output.tum", planar_trajectory(t, run.output_p, run.output_theta, "output"))
    started = run.t_delayed_ns > t[0]
    xd = run.delayed_x[started]
    write_tum(
        folder / "delayed.tum",
        planar_trajectory(run.t_delayed_ns[started], xd[:, 0:2], xd[:, 4], "delayed"),
    )


@dataclass(frozen=True, slots=True)
class PlanarStudy:
    """Where a study was written and what it measured, per experiment: the summary over seeds
    and each seed's metrics (in seed order)."""

    run_dir: Path
    summary: Mapping[ExperimentName, PlanarSummary]
    per_seed: Mapping[ExperimentName, tuple[PlanarMetrics, ...]]


def _run_one(
    config: PlanarConfig, exp: ExperimentName, k: int
) -> tuple[PlanarMetrics, PlanarRun | None]:
    run = run_planar(config, exp, config.seed + k)
    return planar_metrics(run), (run if k == 0 else None)


def run_planar_study(
    config: PlanarConfig, *, runs_root: Path, progress: Progress | None = None, jobs: int = 1
) -> PlanarStudy:
    """Run every configured experiment over ``config.seeds`` seeds and write a run folder.

    Time series and the figure of each experiment come from its first seed; ``metrics.json``
    has every seed's metrics and their summary. ``jobs`` > 1 runs seeds in that many processes
    (results do not depend on it: every run has its own seeded generators).
    """
    if jobs < 1:
        raise EvalError(f"jobs must be >= 1, got {jobs}")
    run_dir = create_run_folder(runs_root, config.name)
    write_text(run_dir / "config.yaml", dump_config(config))
    tasks = [(exp, k) for exp in config.experiments for k in range(config.seeds)]
    found: dict[ExperimentName, dict[int, PlanarMetrics]] = {e: {} for e in config.experiments}
    first_runs: dict[str, PlanarRun] = {}
    done = 0

    def collect(
        exp: ExperimentName, k: int, result: tuple[PlanarMetrics, PlanarRun | None]
    ) -> None:
        nonlocal done
        metrics, run = result
        found[exp][k] = metrics
        append_jsonl(run_dir / "seeds.jsonl", {"experiment": exp, **asdict(metrics)})
        if run is not None:
            first_runs[exp] = run
        done += 1
        if progress is not None:
            progress(done, len(tasks), f"{exp} seed {config.seed + k}")

    run_tasks(
        _run_one,
        [(config, exp, k) for exp, k in tasks],
        lambda i, result: collect(*tasks[i], result),
        jobs=jobs,
    )
    per_seed = {e: tuple(v[k] for k in range(config.seeds)) for e, v in found.items()}
    for exp in config.experiments:
        _write_run_series(first_runs[exp], run_dir / exp)
        plot_planar_run(first_runs[exp], run_dir / "plots" / f"{exp}.png")
    summary = {exp: summarize_seeds(v) for exp, v in per_seed.items()}
    if config.seeds > 1:
        plot_monte_carlo(per_seed, run_dir / "plots" / "monte_carlo.png")
    _write_summary(config, run_dir, per_seed, summary)
    finish_run_folder(run_dir)
    return PlanarStudy(run_dir=run_dir, summary=summary, per_seed=per_seed)


def planar_table(summary: Mapping[ExperimentName, PlanarSummary]) -> list[dict[str, Metric]]:
    """The rows of the study's table (``metrics.json`` and the report): one per experiment."""
    return [
        {
            "experiment": exp,
            "seeds": s.seeds,
            "RMSE delayed (m)": s.rmse_delayed_m.median,
            "RMSE output (m)": s.rmse_output_m.median,
            "floor (m)": s.rmse_floor_m.median,
            "output/floor": s.output_over_floor.median,
            "NEES mean": s.nees_mean.median,
            "GPS fused": s.gps_fused_total,
            "GPS gated": s.gps_rejected_gate_total,
            "GPS too old": s.gps_rejected_too_old_total,
        }
        for exp, s in summary.items()
    ]


def _write_summary(
    config: PlanarConfig,
    run_dir: Path,
    per_seed: Mapping[ExperimentName, tuple[PlanarMetrics, ...]],
    summary: Mapping[ExperimentName, PlanarSummary],
) -> None:
    """metrics.json (every seed's metrics, their summary, the table) and the report."""
    table = planar_table(summary)
    write_json(
        run_dir / "metrics.json",
        {
            "kind": "planar",
            "description": "position RMSE of each estimate against the truth at its own horizon; "
            "floor = delayed estimate re-integrated through the buffered IMU samples; "
            "NEES of the 5-state delayed estimate after the first fused fix",
            "summary": {exp: asdict(s) for exp, s in summary.items()},
            "per_seed": {exp: [asdict(m) for m in ms] for exp, ms in per_seed.items()},
            "table": table,
        },
    )
    headers = list(table[0])
    images = [run_dir / "plots" / f"{exp}.png" for exp in config.experiments]
    if config.seeds > 1:
        images.append(run_dir / "plots" / "monte_carlo.png")
    write_report(
        run_dir / "report.html",
        title=f"Planar delayed-measurement experiments ({config.seeds} seed(s))",
        sections=[
            ReportSection(
                heading="Metrics",
                text="Position RMSE, median over seeds: the delayed estimate against the truth at the "
                "delayed horizon, the output predictor and its floor against the truth now. The floor is "
                "the delayed estimate re-integrated through the buffered IMU samples at every step.",
                tables=[
                    ReportTable(
                        "median over seeds", headers, [[row[h] for h in headers] for row in table]
                    )
                ],
            ),
            ReportSection(heading="Plots (first seed of each experiment)", images=images),
            ReportSection(heading="Configuration", code=dump_config(config)),
        ],
    )
