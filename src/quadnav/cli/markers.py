"""``quadnav markers SOURCE``: thesis 000's marker program on a folder of images, a video or a
camera: poses with covariance to CSV, an overlay video, per-stage timing and the fraction of
frames with a pose."""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.table import Table

from quadnav.cli.common import console, err_console, handle_errors, progress_bar
from quadnav.cli.planar import OutOpt, SetOpt
from quadnav.errors import ConfigError, IoError
from quadnav.eval.report import ReportSection, ReportTable, write_report
from quadnav.io.config import dump_config, load_config
from quadnav.io.frames import VideoOut, open_frames
from quadnav.io.opencv_yaml import read_camera_yaml, read_opencv_yaml
from quadnav.io.run_folder import CsvAppender, create_run_folder, write_json, write_text
from quadnav.vision.config import MarkersConfig, from_thesis_vision_params
from quadnav.vision.markers import MarkerDetector, detector_parameters, get_dictionary
from quadnav.vision.overlay import draw_overlay
from quadnav.vision.pipeline import FramePose, MarkerPipeline

__all__ = ["load_markers_config", "markers_command", "run_markers"]


def load_markers_config(
    params: Path | None, overrides: list[str]
) -> tuple[MarkersConfig, list[str]]:
    """Our YAML, or thesis 000's OpenCV-YAML ``vision_params.yml`` (keys mapped; the ones
    that mean nothing here are returned for a note)."""
    if params is not None and params.is_file() and params.read_bytes()[:9] == b"%YAML:1.0":
        base, ignored = from_thesis_vision_params(read_opencv_yaml(params))
        if "camera_file" in base and not (params.parent / base["camera_file"]).is_file():
            del base["camera_file"]  # the thesis's relative path points into its own tree
        elif "camera_file" in base:
            base["camera_file"] = str(params.parent / base["camera_file"])
        return load_config(MarkersConfig, None, overrides, base=base), ignored
    return load_config(MarkersConfig, params, overrides), []


_COV_INDEX = np.triu_indices(6)
_COV_NAMES = ["x", "y", "z", "rx", "ry", "rz"]
POSE_COLUMNS = [
    "t_ns", "frame", "x_m", "y_m", "z_m", "roll_deg", "pitch_deg", "yaw_deg",
    "qx", "qy", "qz", "qw", "n_markers", "ids", "n_points", "rms_px", "detect_ms", "pose_ms",
    "reason",
    *(f"cov_{_COV_NAMES[i]}_{_COV_NAMES[j]}" for i, j in zip(*_COV_INDEX, strict=True)),
]  # fmt: skip


def _pose_row(frame: int, fp: FramePose) -> list[Any]:
    """One line of ``poses.csv`` (:data:`POSE_COLUMNS`); NaN where the frame has no pose, and
    why in ``reason``."""
    if fp.pose is not None:
        R = fp.pose.T_W_B.R_A_B
        pose = [*fp.pose.T_W_B.p_A_B, *R.as_euler("ZYX", degrees=True)[::-1], *R.as_quat()]
        cov = list(fp.pose.cov[_COV_INDEX])
    else:
        pose, cov = [math.nan] * 10, [math.nan] * 21
    ids = " ".join(str(i) for i in sorted(fp.detections.ids.tolist())) or "-"
    return [fp.t_ns, frame, *pose, len(fp.detections), ids, fp.n_points, fp.rms_px,
            fp.detect_ms, fp.pose_ms, fp.reason or "-", *cov]  # fmt: skip


def run_markers(
    cfg: MarkersConfig,
    source: str,
    out: Path,
    *,
    progress: Any = None,
    mavlink: str | None = None,
    setpoints: Path | None = None,
) -> dict[str, Any]:
    """Process every frame of ``source``; write the run folder; return the statistics. With
    ``mavlink``, be thesis 000's companion computer: each pose goes to the autopilot as a
    VISION_POSITION_ESTIMATE with its covariance, with heartbeats and, from ``setpoints``
    (a trajectory file), SET_POSITION_TARGET_LOCAL_NED at the frame rate."""
    if cfg.camera_file is None:
        raise ConfigError(
            "no camera calibration: give --camera cal.yml (OpenCV YAML) or camera_file in the parameters"
        )
    camera = read_camera_yaml(cfg.camera_file)
    values: dict[str, Any] = read_opencv_yaml(cfg.detector_file) if cfg.detector_file else {}
    values.update(cfg.detector)
    det_params, unknown = detector_parameters(values)
    frames = open_frames(source, fps=cfg.fps)
    run_dir = create_run_folder(out, "markers")
    write_text(run_dir / "config.yaml", dump_config(cfg))
    video = VideoOut(run_dir / "overlay.mp4", frames.fps) if cfg.video else None
    pipeline: MarkerPipeline | None = None
    if cfg.target != "marker" or cfg.marker_id is not None:
        pipeline = MarkerPipeline(camera, cfg.marker_map(), cfg.T_B_C(), params=det_params,
                                  prior_sigma_px=cfg.prior_sigma_px, max_rms_px=cfg.max_rms_px,
                                  charuco_min_markers=cfg.charuco.min_markers,
                                  board_marker_fallback=cfg.charuco.marker_fallback)  # fmt: skip
    detector = MarkerDetector(get_dictionary(cfg.dictionary), det_params)
    link = None
    if mavlink is not None:
        from quadnav.io.mavlink import MavlinkLink

        link = MavlinkLink(mavlink, system=1, component=197)
    plan = None
    if setpoints is not None:
        from quadnav.io.trajectory_io import read_trajectory

        plan = read_trajectory(setpoints)
    t_first: int | None = None
    last_hb = -(10**12)
    results: list[FramePose] = []
    frame_idx: list[int] = []
    skipped: list[str] = []
    world_id: int | None = cfg.marker_id
    total = (
        frames.total
        if cfg.max_frames is None
        else min(frames.total or cfg.max_frames, cfg.max_frames)
    )
    n_total = 0
    # one row per frame as it comes, flushed: a run stopped half way keeps what it made
    poses_csv = CsvAppender(run_dir / "poses.csv", POSE_COLUMNS)
    for fr in frames:
        if cfg.max_frames is not None and fr.index >= cfg.max_frames:
            break
        n_total += 1
        if fr.image is None:
            skipped.append(f"frame {fr.index}: {fr.error}")
        else:
            probe = None
            if pipeline is None:
                # One marker is the world: the lowest id of the first frame that shows any.
                probe = detector.detect(fr.image)
                if len(probe):
                    world_id = int(probe.ids.min())
                    pipeline = MarkerPipeline(camera, cfg.marker_map(world_id), cfg.T_B_C(), params=det_params,
                                              prior_sigma_px=cfg.prior_sigma_px, max_rms_px=cfg.max_rms_px)  # fmt: skip
            if pipeline is not None:
                fp = pipeline.process(fr.image, fr.t_ns)
                results.append(fp)
                poses_csv.append(_pose_row(fr.index, fp))
                frame_idx.append(fr.index)
                if link is not None:
                    t_first = fr.t_ns if t_first is None else t_first
                    if fr.t_ns - last_hb >= 1_000_000_000:
                        link.heartbeat()
                        last_hb = fr.t_ns
                    if fp.pose is not None:
                        link.send_vision_position_estimate(fr.t_ns, fp.pose.T_W_B, fp.pose.cov)
                    if plan is not None:
                        t_rel = plan.t_ns[0] + (fr.t_ns - t_first)
                        k = min(int(np.searchsorted(plan.t_ns, t_rel)), len(plan) - 1)
                        link.send_position_setpoint(plan.p_W_B[k], 0.0)
                    link.poll()
                if video is not None:
                    T_C_W = (fp.pose.T_W_B @ cfg.T_B_C()).inverse() if fp.pose is not None else None
                    text = f"frame {fr.index}  markers {len(fp.detections)}" + (
                        f"  z {fp.pose.T_W_B.p_A_B[2]:.3f} m  rms {fp.rms_px:.2f} px"
                        if fp.pose is not None
                        else "  no pose"
                    )
                    video.write(draw_overlay(fr.image, fp.detections, camera, T_C_W, text=text))
            elif video is not None and probe is not None:
                video.write(
                    draw_overlay(fr.image, probe, camera, None, text=f"frame {fr.index}  no marker")
                )
        if progress:
            progress(
                fr.index + 1, total or 0, f"{len([r for r in results if r.pose is not None])} poses"
            )
    poses_csv.close()
    if video is not None:
        video.close()
    ok = [r for r in results if r.pose is not None]
    t = np.array([r.t_ns for r in results], dtype=np.int64)
    pos = np.array(
        [r.pose.T_W_B.p_A_B if r.pose is not None else np.full(3, np.nan) for r in results]
    ).reshape(-1, 3)
    # Jitter: the pose noise from frame to frame. A moving camera's smooth motion cancels in
    # the second difference p[k+1] - 2 p[k] + p[k-1] of consecutive frames; white noise of
    # sigma per axis gives it a variance of 6 sigma^2.
    fidx = np.array(frame_idx)
    have = np.isfinite(pos[:, 0])
    if len(pos) > 2:
        triple = have[2:] & have[1:-1] & have[:-2] & (fidx[2:] - fidx[:-2] == 2)
        d2 = (pos[2:] - 2 * pos[1:-1] + pos[:-2])[triple]
        steps = np.linalg.norm(d2, axis=1) / math.sqrt(6.0)
    else:
        steps = np.zeros(0)
    det_ms = np.array([r.detect_ms for r in results])
    pose_ms = np.array([r.pose_ms for r in ok])
    stats = {
        "source": frames.description, "frames": n_total, "frames_processed": len(results),
        "frames_skipped": len(skipped), "skipped": skipped[:50],
        "frames_with_pose": len(ok), "fraction_with_pose": len(ok) / n_total if n_total else 0.0,
        "frames_rejected": sum(r.pose is None and r.reason != "no_target" for r in results),
        "rejected_by_reason": dict(Counter(r.reason for r in results if r.pose is None)),
        "world_marker_id": world_id if cfg.target == "marker" else None,
        "jitter_rms_mm": float(np.sqrt(np.mean(steps**2)) * 1e3) if len(steps) else math.nan,
        "jitter_median_mm": float(np.median(steps) * 1e3) if len(steps) else math.nan,
        "detect_ms_median": float(np.median(det_ms)) if len(det_ms) else math.nan,
        "pose_ms_median": float(np.median(pose_ms)) if len(pose_ms) else math.nan,
        "rms_px_median": float(np.median([r.rms_px for r in ok])) if ok else math.nan,
        "unknown_detector_parameters": unknown,
        "run_dir": str(run_dir),
    }  # fmt: skip
    if link is not None:
        stats["mavlink"] = {"url": mavlink, "sent": dict(link.stats.sent), "received": dict(link.stats.received),
                            "bad_packets": link.stats.bad_packets}  # fmt: skip
        link.close()
    write_json(run_dir / "stats.json", stats)
    images = _plots(run_dir, t, pos, det_ms, pose_ms)
    rows = [
        [k, v]
        for k, v in stats.items()
        if k not in ("skipped", "run_dir", "unknown_detector_parameters")
    ]
    write_report(run_dir / "report.html", title=f"markers: {frames.description}", sections=[
        ReportSection("Statistics", tables=[ReportTable("per run", ["measure", "value"], rows)]),
        ReportSection("Plots", images=images),
        ReportSection("Configuration", code=dump_config(cfg)),
    ])  # fmt: skip
    return stats


def _plots(
    run_dir: Path, t: np.ndarray, pos: np.ndarray, det_ms: np.ndarray, pose_ms: np.ndarray
) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    (run_dir / "plots").mkdir(exist_ok=True)
    paths = []
    if len(t):
        fig, axes = plt.subplots(3, 1, figsize=(10, 6), sharex=True, constrained_layout=True)
        ts = (t - t[0]) * 1e-9
        for k, ax in enumerate(axes):
            ax.plot(ts, pos[:, k], ".", ms=2)
            ax.set_ylabel(f"{'xyz'[k]} (m)")
            ax.grid(True, alpha=0.3)
        axes[-1].set_xlabel("t (s)")
        fig.suptitle("vehicle position from the markers")
        paths.append(run_dir / "plots" / "position.png")
        fig.savefig(paths[-1], dpi=100)
        plt.close(fig)
        fig, ax = plt.subplots(figsize=(7, 4), constrained_layout=True)
        ax.hist(det_ms, bins=40, alpha=0.6, label="detection")
        if len(pose_ms):
            ax.hist(pose_ms, bins=40, alpha=0.6, label="pose")
        ax.set_xlabel("ms per frame")
        ax.legend()
        paths.append(run_dir / "plots" / "timing.png")
        fig.savefig(paths[-1], dpi=100)
        plt.close(fig)
    return paths


@handle_errors
def markers_command(
    source: Annotated[str, typer.Argument(help="image folder, video file or camera index (0)")],
    params: Annotated[
        Path | None,
        typer.Option("--params", help="parameters: our YAML or the thesis's vision_params.yml"),
    ] = None,
    camera: Annotated[
        Path | None, typer.Option("--camera", help="calibration, OpenCV YAML")
    ] = None,
    set_: SetOpt = None,
    out: OutOpt = Path("runs"),
    mavlink: Annotated[
        str | None,
        typer.Option(
            "--mavlink", help="send the poses to an autopilot, e.g. udpout:127.0.0.1:14540"
        ),
    ] = None,
    setpoints: Annotated[
        Path | None,
        typer.Option(
            "--setpoints", help="with --mavlink: a trajectory to send as position setpoints"
        ),
    ] = None,
) -> None:
    """Detect markers and estimate the vehicle's pose in every frame of SOURCE.

    Examples:

      quadnav markers board12_17.mp4 --params vision_params.yml --camera cal.yml

      quadnav markers photos/ --camera cal.yml --set dictionary=DICT_6X6_250 --set marker_length_m=0.05
    """
    overrides = list(set_ or [])
    if camera is not None:
        if not camera.is_file():
            raise IoError(f"{camera}: no such file")
        overrides.append(f"camera_file={camera}")
    cfg, ignored = load_markers_config(params, overrides)
    if ignored:
        err_console.print(f"note: parameters not used here: {', '.join(ignored)}", highlight=False)
    with progress_bar("markers") as update:
        stats = run_markers(cfg, source, out, progress=update, mavlink=mavlink, setpoints=setpoints)
    table = Table(title=f"markers: {stats['source']}")
    table.add_column("measure")
    table.add_column("value", justify="right")
    table.add_row("frames", str(stats["frames"]))
    table.add_row("frames skipped (unreadable)", str(stats["frames_skipped"]))
    table.add_row(
        "frames with a pose", f"{stats['frames_with_pose']} ({stats['fraction_with_pose']:.1%})"
    )
    table.add_row("frames rejected (degenerate view, bad fit)", str(stats["frames_rejected"]))
    table.add_row(
        "frame-to-frame jitter, RMS / median (mm)",
        f"{stats['jitter_rms_mm']:.2f} / {stats['jitter_median_mm']:.2f}",
    )
    table.add_row("detection, median (ms)", f"{stats['detect_ms_median']:.2f}")
    table.add_row("pose, median (ms)", f"{stats['pose_ms_median']:.2f}")
    table.add_row("reprojection error, median (px)", f"{stats['rms_px_median']:.3f}")
    if "mavlink" in stats:
        sent = stats["mavlink"]["sent"]
        table.add_row("MAVLink messages sent", ", ".join(f"{k} {v}" for k, v in sent.items()))
    console.print(table)
    console.print(stats["run_dir"], soft_wrap=True, highlight=False)
