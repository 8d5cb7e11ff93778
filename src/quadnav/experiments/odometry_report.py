"""The plots and the HTML report of an odometry run folder (:mod:`quadnav.experiments.odometry_run`)."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from quadnav.errors import EvalError, IoError
from quadnav.eval.na import fmt_metric
from quadnav.eval.vio_metrics import VioMetrics
from quadnav.experiments.odometry_run import OdometryRun, OdometryTiming
from quadnav.geometry.trajectory import Trajectory
from quadnav.odometry import VisualOdometry
from quadnav.units import ns_to_s

if TYPE_CHECKING:
    from quadnav.eval.loop_eval import LoopEvaluation
    from quadnav.eval.report import ReportSection

__all__ = ["loop_evaluation", "write_odometry_outputs"]


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _plot_path(path: Path, truth: Trajectory | None, est: Trajectory, t0_ns: int) -> Path:
    """Top view and height against time: the estimate (4-DoF aligned when there is a truth)
    and the ground truth dashed."""
    from quadnav.eval.plots import thinned

    plt = _pyplot()
    fig, (top, up) = plt.subplots(1, 2, figsize=(14, 5.5), constrained_layout=True)
    for tr, style, label in ((truth, "--", "ground truth"), (est, "-", "VIO")):
        if tr is None or len(tr) == 0:
            continue
        s = thinned(len(tr))  # a bounded number of points however long the run
        p = tr.p_W_B[s]
        top.plot(p[:, 0], p[:, 1], style, lw=1.2, label=label)
        up.plot((tr.t_ns[s] - t0_ns) * 1e-9, p[:, 2], style, lw=1.2, label=label)
    top.set_aspect("equal", adjustable="datalim")
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    top.set_title("Top view" + (" (VIO aligned in position and yaw)" if truth is not None else ""))
    up.set_xlabel("t (s from the run's start)")
    up.set_ylabel("z (m)")
    up.set_title("Height")
    for ax in (top, up):
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _t0(truth: Trajectory | None, est: Trajectory) -> int:
    """The time the plots count from: the truth's start, else the estimate's."""
    return int(truth.t_ns[0]) if truth is not None else int(est.t_ns[0]) if len(est) else 0


def _plot_timing(path: Path, timing: OdometryTiming) -> Path:
    plt = _pyplot()
    names = list(timing.stage_ms_per_frame)
    fig, ax = plt.subplots(figsize=(9, 0.5 * len(names) + 1.5), constrained_layout=True)
    ax.barh(names, [timing.stage_ms_per_frame[n] for n in names])
    ax.invert_yaxis()
    ax.set_xlabel("ms per camera frame")
    ax.set_title(f"Per stage: {timing.frames_per_s:.1f} frames/s for the estimator")
    ax.grid(True, axis="x", alpha=0.3)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


@contextmanager
def _writing_plots(run_dir: Path) -> Iterator[None]:
    """A plot that cannot be written (a full disk, say: matplotlib and PIL raise the OSError as
    it is) is one line naming the file."""
    try:
        yield
    except OSError as exc:
        where = exc.filename or run_dir / "plots"
        raise IoError(f"cannot write {where}: {exc.strerror or exc}") from None


#: The window of the NEES plot's running means (s).
NEES_WINDOW_S = 2.0


def write_nees(
    run_dir: Path, ref: Trajectory | None, est: Trajectory | None, cov: Any, levelled: bool
) -> None:
    """``nees.csv``, each pose's NEES (6 degrees of freedom) and its rotation's and
    translation's alone (3 each), in the gauge the estimator's covariance has; and
    ``plots/nees.png``, their running means over dimension against time. Nothing without a
    truth or a covariance."""
    from quadnav.eval.vio_metrics import in_estimator_gauge, pose_nees_parts
    from quadnav.io.run_folder import write_csv

    if ref is None or est is None or cov is None or len(est) < 2:
        return
    try:
        parts = pose_nees_parts(ref, in_estimator_gauge(ref, est, levelled), cov)
    except EvalError:
        return
    names = ("nees_pose", "nees_rotation", "nees_translation")
    write_csv(run_dir / "nees.csv", {"t_ns": est.t_ns} | dict(zip(names, parts.T, strict=True)))
    with _writing_plots(run_dir):
        _plot_nees(run_dir / "plots" / "nees.png", ns_to_s(est.t_ns - est.t_ns[0]), parts)


def _plot_nees(path: Path, t_s: Any, parts: Any) -> None:
    plt = _pyplot()
    dt = float(np.median(np.diff(t_s))) if len(t_s) > 1 else 1.0
    n = min(max(1, round(NEES_WINDOW_S / max(dt, 1e-9))), len(t_s))  # (a short run: all of it)
    kernel = np.ones(n) / n
    fig, ax = plt.subplots(figsize=(9, 4), constrained_layout=True)
    for k, (label, dof) in enumerate(
        (("pose (6)", 6), ("rotation (3)", 3), ("translation (3)", 3))
    ):
        mean = np.convolve(parts[:, k] / dof, kernel, mode="same")
        ax.plot(t_s, mean, label=f"{label}: {np.mean(parts[:, k]) / dof:.2f} over the run")
    # (successive poses' errors are correlated: a band for independent draws would be too narrow)
    ax.axhspan(0.5, 2.0, color="0.9", label="0.5-2: honest within a factor of 2")
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_yscale("log")
    ax.set_xlabel("time since the first estimate (s)")
    ax.set_ylabel(f"NEES / dof, {NEES_WINDOW_S:g} s running mean")
    ax.set_title("Consistency: 1 is honest, above it the estimate claims too much")
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _write_plots(
    run: OdometryRun, ref: Trajectory | None, est_m: Trajectory | None, truth: Trajectory | None,
    est: Trajectory,
) -> list[Path]:  # fmt: skip
    from quadnav.eval.align import align
    from quadnav.eval.metrics import ape
    from quadnav.eval.plots import plot_errors

    plots = run.run_dir / "plots"
    t0 = _t0(truth, est)
    images = []
    if ref is not None and est_m is not None and len(est_m) >= 2:
        try:
            aligned, _ = align(ref, est_m, "4dof")
        except EvalError:
            aligned = None
        if aligned is not None:
            images.append(_plot_path(plots / "trajectory.png", truth, aligned, t0))
            plot_errors(
                ref,
                aligned,
                ape(ref, aligned),
                plots / "error.png",
                what="APE after 4-DoF alignment (m)",
            )
            images.append(plots / "error.png")
    elif len(est):
        images.append(_plot_path(plots / "trajectory.png", None, est, t0))
    if (plots / "nees.png").is_file():  # (written before, by write_nees)
        images.append(plots / "nees.png")
    if run.timing.stage_ms_per_frame:
        images.append(_plot_timing(plots / "timing.png", run.timing))
    return images


def _final_rows(final: Mapping[str, object] | None) -> list[list[object]]:
    """The final trajectory's rows (``estimate_final.tum``; none without one)."""
    if not final:
        return []
    rows: list[list[object]] = []
    for key, label in (("ape_se3", "SE(3)"), ("ape_sim3", "Sim(3)")):
        ape = final.get(key)
        if isinstance(ape, Mapping) and isinstance(ape.get("rmse_m"), int | float):
            rows.append([f"final trajectory (not causal): APE {label} RMSE (m)",
                         fmt_metric(float(ape["rmse_m"]), ".4g")])  # fmt: skip
    sm = final.get("smoothing")
    if isinstance(sm, Mapping):
        rows.append(["final smoothing: segments, failed, loops as factors (of them as "
                     "observations; unused)",
                     f"{sm.get('segments')}, {sm.get('failed')}, {sm.get('loops', 0)} "
                     f"({sm.get('loops_observed', 0)}; {sm.get('loops_unused', 0)})"])  # fmt: skip
    return rows


def _metric_rows(m: VioMetrics, final: Mapping[str, object] | None = None) -> list[list[object]]:
    """The report's metrics, numbers to 4 significant digits (``metrics.json`` keeps them all);
    the final trajectory's APE after the causal one's where the run has one."""

    def cell(v: object, key: str | None = None) -> str:
        value = getattr(v, key) if key is not None and not isinstance(v, str) else v
        return fmt_metric(value, ".4g")

    return [
        ["APE 4-DoF RMSE (m)", cell(m.ape_4dof, "rmse_m")],
        ["APE 4-DoF median / max (m)", f"{cell(m.ape_4dof, 'median_m')} / {cell(m.ape_4dof, 'max_m')}"],
        ["APE SE(3) RMSE (m)", cell(m.ape_se3, "rmse_m")],
        ["APE Sim(3) RMSE (m), scale", f"{cell(m.ape_sim3, 'rmse_m')}, {cell(m.ape_sim3, 'scale')}"],
        *_final_rows(final),
        ["RPE per 1 m: trans RMSE (m), rot RMSE (deg)", f"{cell(m.rpe_1m, 'trans_rmse_m')}, {cell(m.rpe_1m, 'rot_rmse_deg')}"],
        ["RPE per 10 m: trans RMSE (m), rot RMSE (deg)", f"{cell(m.rpe_10m, 'trans_rmse_m')}, {cell(m.rpe_10m, 'rot_rmse_deg')}"],
        ["final position error (m)", cell(m.final_error_m)],
        ["drift, final (%)", cell(m.drift_final_pct)],
        ["drift, RPE (%)", cell(m.drift_rpe_pct)],
        ["gravity error at the start (deg)", cell(m.gravity_error_deg)],
        ["pose NEES / 6 (1: consistent)", cell(m.nees_pose, "mean_over_dof")],
        ["distance travelled (m)", cell(m.distance_m)],
        ["frames with an estimate", f"{m.frames_with_estimate} of {m.frames} ({100 * m.fraction_with_estimate:.1f} %)"],
        ["initialised after (s)", cell(m.initialized_after_s)],
        ["failures, re-initialisations, recoveries", f"{m.failures}, {m.reinitializations}, {m.recoveries}"],
        ["rejected images", m.rejected_images],
    ]  # fmt: skip


_PLACE_HEADERS = (
    "t (s)", "keyframe", "matched keyframe", "stage", "PnP inliers", "truth distance (m)",
    "truth yaw (deg)", "correction (m)", "measured error (m)", "measured error (deg)", "verdict",
)  # fmt: skip


def loop_evaluation(
    vio: VisualOdometry, keyframes: Trajectory, truth: Trajectory | None
) -> LoopEvaluation | None:
    """Loop closure's places and keyframes judged against the truth (None: the odometry
    closes no loops), recall counted over the detector's excluded window and the closer's
    gap between loops (:mod:`quadnav.eval.loop_eval`)."""
    from quadnav.eval.loop_eval import LoopEvalConfig, evaluate_loops, revisit_bound
    from quadnav.loop import LoopClosure

    if not isinstance(vio, LoopClosure):
        return None
    cfg = LoopEvalConfig(
        exclude_keyframes=max(1, vio.config.detector.exclude_recent),
        recall_window=vio.config.min_keyframes_between,
    )
    ev = evaluate_loops(vio.own_places(), keyframes, vio.corrected_keyframes(), truth, cfg)
    steps = vio.step_variances()
    step_var = None if steps is None else np.array([steps.get(int(t), 0.0) for t in keyframes.t_ns])
    seg = vio.segment_by_time()
    segments = np.array([seg.get(int(t), -1) for t in keyframes.t_ns], dtype=np.int64)
    bound = revisit_bound(
        keyframes, truth, vio.config.graph, cfg, step_var=step_var, segments=segments
    )
    return replace(ev, bound_m=bound)


def _loop_section(loop: LoopEvaluation, path: Path, t0_ns: int) -> ReportSection:
    """The report's loop closure: its metrics, each recognised place, the figure."""
    from quadnav.eval.loop_eval import plot_loop_graph
    from quadnav.eval.report import ReportSection, ReportTable

    def num(x: float | None, spec: str = ".3f") -> str:
        return "" if x is None else format(x, spec)

    c = loop.config
    metrics = [[k, fmt_metric(v, ".4g")] for k, v in loop.as_metrics().items()]
    places = [
        [f"{ns_to_s(p.t_new_ns - t0_ns):.2f}", p.new, p.old, p.stage, p.n_pnp,
         num(p.truth_distance_m), num(p.truth_yaw_deg, ".1f"), num(p.correction_m),
         num(p.error_m), num(p.error_deg, ".2f"), p.verdict]
        for p in loop.places
    ]  # fmt: skip
    text = (
        f"A loop is true when its measured pose is within {c.max_error_m:g} m and "
        f"{c.max_error_deg:g} deg of the truth's; a keyframe revisits a place when the truth "
        f"puts one at least {c.exclude_keyframes} keyframes earlier under {c.same_place_m:g} m "
        f"and {c.same_place_yaw_deg:g} deg of yaw from it, and "
        f"is found when a true loop closed within {c.recall_window} keyframes of it. "
        "Correction: how far the loop's measurement puts the new keyframe from where the odometry "
        "had it, relative to the old keyframe."
    )
    return ReportSection(
        "Loop closure",
        text=text,
        tables=[
            ReportTable("against the ground truth", ["metric", "value"], metrics),
            ReportTable(
                "every recognised place (t: s from the run's start)", _PLACE_HEADERS, places
            ),
        ],
        images=[plot_loop_graph(loop, path, t0_ns)],
    )


def write_odometry_outputs(
    run: OdometryRun, ref: Trajectory | None, est_m: Trajectory | None, truth: Trajectory | None,
    est: Trajectory, loop: LoopEvaluation | None = None,
) -> None:  # fmt: skip
    """The plots and ``report.html`` of a finished run (with loop closure's section when
    ``loop`` is given)."""
    from quadnav.eval.report import ReportSection, ReportTable, write_report

    with _writing_plots(run.run_dir):
        images = _write_plots(run, ref, est_m, truth, est)
        extra = (
            [_loop_section(loop, run.run_dir / "plots" / "loop_graph.png", _t0(truth, est))]
            if loop is not None
            else []
        )
    t = run.timing
    events = [
        [f"{ns_to_s(e.t_ns - (int(est.t_ns[0]) if len(est) else e.t_ns)):.2f}", e.kind, e.detail]
        for e in run.events
    ]
    stages = [
        [n, t.stage_ms_per_call[n], t.stage_ms_per_frame.get(n, 0.0), t.stage_calls.get(n, 0)]
        for n in t.stage_ms_per_call
    ]
    write_report(
        run.run_dir / "report.html",
        title=f"VIO on {run.dataset} ({run.camera})",
        sections=[
            ReportSection(
                "Metrics",
                text=run.metrics.drift_definitions,
                tables=[
                    ReportTable(
                        "against the ground truth",
                        ["metric", "value"],
                        _metric_rows(run.metrics, run.final),
                    )
                ],
            ),
            ReportSection(
                "Events",
                tables=[
                    ReportTable(
                        "t (s from the first estimate)", ["t (s)", "kind", "detail"], events
                    )
                ],
            ),
            *extra,
            ReportSection(
                "Timing",
                text=f"{t.frames} frames, {t.frames_per_s:.1f} frames/s for the estimator, {t.wall_s:.1f} s wall time for the run",
                tables=[
                    ReportTable(
                        "per stage", ["stage", "ms per call", "ms per frame", "calls"], stages
                    )
                ],
            ),
            ReportSection("Plots", images=images),
            ReportSection("Notes", text="\n".join(run.notes) or "none"),
            ReportSection("Configuration", code=(run.run_dir / "config.yaml").read_text()),
        ],
    )
