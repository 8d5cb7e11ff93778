"""Thesis 000's marker program (``quadnav markers``) as a run: a folder of images, a video or a
camera through the marker pipeline into a run folder: poses with covariance to CSV, an overlay
video, per-stage timing and the fraction of frames with a pose, optionally sent over MAVLink."""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import ConfigError, VisionError
from quadnav.eval.report import ReportSection, ReportTable, write_report
from quadnav.geometry.camera import PinholeCamera
from quadnav.io.config import dump_config, load_config
from quadnav.io.frames import (
    CaptureProperty,
    CaptureRequest,
    FrameSource,
    FrameWindow,
    ImagesOut,
    VideoOut,
    display_missing,
    open_frames,
    quiet_libraries,
)
from quadnav.io.opencv_yaml import opencv_error_text, read_camera_yaml, read_opencv_yaml
from quadnav.io.run_folder import CsvAppender, create_run_folder, write_json, write_text
from quadnav.vision.config import MarkersConfig, from_thesis_vision_params
from quadnav.vision.markers import (
    MarkerDetections,
    MarkerDetector,
    detector_parameters,
    get_dictionary,
    to_gray,
)
from quadnav.vision.overlay import draw_overlay
from quadnav.vision.pipeline import FramePose, MarkerPipeline

__all__ = [
    "POSE_COLUMNS",
    "MarkersStats",
    "MavlinkCounts",
    "fit_calibration",
    "load_markers_config",
    "run_markers",
    "window_or_not",
]


def load_markers_config(
    params: Path | None, overrides: list[str]
) -> tuple[MarkersConfig, list[str]]:
    """Our YAML, or thesis 000's OpenCV-YAML ``vision_params.yml`` (keys mapped; the ones
    that mean nothing here are returned for a note)."""
    if params is not None and params.is_file() and params.read_bytes()[:9] == b"%YAML:1.0":
        try:
            base, ignored = from_thesis_vision_params(read_opencv_yaml(params))
        except VisionError as exc:
            raise ConfigError(f"{params}: {exc}") from None
        camera_file = params.parent / str(base.get("camera_file", ""))
        if "camera_file" in base and not camera_file.is_file():
            del base["camera_file"]  # the thesis's relative path points into its own tree
        elif "camera_file" in base:
            base["camera_file"] = str(camera_file)
        return load_config(MarkersConfig, None, overrides, base=base), ignored
    return load_config(MarkersConfig, params, overrides), []


def window_or_not(
    cfg: MarkersConfig, *, asked: bool, display: Callable[[], str] = display_missing
) -> tuple[MarkersConfig, str]:
    """The configuration without its window, and a note saying why, when a parameter file asks
    for one (``show``, the thesis's ``open_window``) on a machine with no display (``display``
    says why not, '' when there is one). A window ``asked`` for on the command line (``--show``,
    ``--set show=true``) stays: opening it is then an error."""
    if not cfg.show or asked:
        return cfg, ""
    why = display()
    if not why:
        return cfg, ""
    note = (
        f"no window: the parameters ask for one (show / the thesis's open_window) but {why}; "
        "running without it (--show insists, --no-show skips this note)"
    )
    return cfg.model_copy(update={"show": False}), note


#: Called after each frame with (frames done, frames in all or 0 when unknown, a short text).
Progress = Callable[[int, int, str], None]
#: Called with a one-line note for the user while the run goes on.
Notify = Callable[[str], None]

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


def fit_calibration(camera: PinholeCamera, size: tuple[int, int]) -> tuple[PinholeCamera, str]:
    """The calibration for frames of ``size`` (width, height): as it is, or scaled when only
    the resolution differs (same aspect ratio; returns a note saying so). A calibration of
    another shape is an error: its focal lengths and centre do not fit these frames."""
    w, h = size
    if (w, h) == (camera.width, camera.height):
        return camera, ""
    sx, sy = w / camera.width, h / camera.height
    what = f"the calibration (--camera / camera_file) is for {camera.width}x{camera.height} images"
    if abs(sx / sy - 1.0) > 2e-3:
        raise ConfigError(
            f"{what}, the frames are {w}x{h} (another aspect ratio): calibrate at {w}x{h}"
        )
    return camera.scaled(w, h), f"{what}; scaled x{sx:.4g} to the frames' {w}x{h}"


def _capture_request(cfg: MarkersConfig) -> CaptureRequest:
    """The camera settings the configuration gives (an unset ``fps`` is not asked)."""
    return CaptureRequest(
        fps=cfg.fps if "fps" in cfg.model_fields_set else None,
        frame_width_px=cfg.frame_width_px,
        frame_height_px=cfg.frame_height_px,
        exposure_time_100us=cfg.exposure_time_100us,
    )


def _time_base(cfg: MarkersConfig, frames: FrameSource) -> str:
    if frames.time_base == "timestamps":
        return f"the video's timestamps ({frames.fps:g} fps)"
    if frames.time_base == "clock":
        return "arrival time of each frame (camera)"
    given = "fps" if "fps" in cfg.model_fields_set else "the default; set fps or --fps"
    what = "images have" if frames.kind == "images" else "the stream has"
    return f"{cfg.fps:g} fps ({given}; {what} no timestamps)"


class _Overlay:
    """Where the drawn frames go: the overlay video, a window, PNG files."""

    def __init__(
        self,
        cfg: MarkersConfig,
        run_dir: Path,
        fps: float,
        camera: PinholeCamera,
        det_params: cv2.aruco.DetectorParameters,
        window: FrameWindow | None,
        *,
        expected_frames: int | None = None,
        notify: Notify | None = None,
    ) -> None:
        self.video = VideoOut(run_dir / "overlay.mp4", fps) if cfg.video else None
        self.images = (
            ImagesOut(run_dir / "images", max_bytes=round(cfg.max_images_mb * 1e6))
            if cfg.write_images
            else None
        )
        self.max_images_mb, self.expected_frames = cfg.max_images_mb, expected_frames
        self.notify: Notify = notify if notify is not None else (lambda text: None)
        self.window, self.camera = window, camera
        # the candidates the detector turned down (a ChArUco detection does not return them)
        self.rejected = (
            cv2.aruco.ArucoDetector(get_dictionary(cfg.dictionary), det_params)
            if cfg.show_rejected
            else None
        )
        self.T_B_C = cfg.T_B_C()
        self.stopped = False

    @property
    def active(self) -> bool:
        return self.video is not None or self.images is not None or self.window is not None

    def frame(
        self, index: int, image: NDArray[Any], fp: FramePose | None, probe: MarkerDetections | None
    ) -> None:
        if not self.active:
            return
        rejected = None
        if self.rejected is not None:
            cand = self.rejected.detectMarkers(to_gray(image))[2]
            rejected = np.asarray(cand, np.float64).reshape(-1, 4, 2)
        if fp is None:
            det = probe if probe is not None else MarkerDetections.from_opencv((), None)
            img = draw_overlay(
                image, det, self.camera, None, text=f"frame {index}  no marker", rejected=rejected
            )
        else:
            T_C_W = (fp.pose.T_W_B @ self.T_B_C).inverse() if fp.pose is not None else None
            text = f"frame {index}  markers {len(fp.detections)}" + (
                f"  z {fp.pose.T_W_B.p_A_B[2]:.3f} m  rms {fp.rms_px:.2f} px"
                if fp.pose is not None
                else "  no pose"
            )
            img = draw_overlay(
                image, fp.detections, self.camera, T_C_W, text=text, rejected=rejected
            )
        if self.video is not None:
            self.video.write(img)
        if self.images is not None:
            self._write_image(index, img)
        if self.window is not None and not self.window.show(img):
            self.stopped = True

    def _write_image(self, index: int, img: NDArray[Any]) -> None:
        """One overlay frame to images/; where and how much when the first is written, and
        once when the cap (``max_images_mb``) stops them."""
        images = self.images
        assert images is not None
        first = images.frames == 0 and images.refused == 0
        if not images.write(index, img):
            if images.refused == 1:
                self.notify(
                    f"images: stopped at {images.bytes / 1e6:.1f} MB in {images.folder} "
                    f"(max_images_mb / --max-images-mb {self.max_images_mb:g}); "
                    "the frames after it are not written"
                )
            return
        if first:
            each_mb, n = images.bytes / 1e6, self.expected_frames
            est = f"about {each_mb * n:.0f} MB for {n} frames" if n else "the frame count unknown"
            self.notify(
                f"images: each overlay frame to {images.folder}, {each_mb:.2f} MB each, {est}; "
                f"stops at {self.max_images_mb:g} MB (max_images_mb / --max-images-mb)"
            )

    def close(self) -> None:
        if self.video is not None:
            self.video.close()
        if self.window is not None:
            self.window.close()


class _Companion:
    """Thesis 000's companion computer: each pose to the autopilot as a
    VISION_POSITION_ESTIMATE with its covariance, heartbeats at 1 Hz and, from a trajectory
    file, SET_POSITION_TARGET_LOCAL_NED at the frame rate."""

    def __init__(self, url: str, setpoints: Path | None, *, allow_remote: bool = False) -> None:
        from quadnav.io.mavlink import MavlinkLink

        self.url = url
        self.link = MavlinkLink(url, system=1, component=197, allow_remote=allow_remote)
        self.plan = None
        if setpoints is not None:
            from quadnav.io.trajectory_io import read_trajectory

            self.plan = read_trajectory(setpoints)
        self.t_first: int | None = None
        self.last_hb = -(10**12)

    def send(self, t_ns: int, fp: FramePose) -> None:
        link = self.link
        self.t_first = t_ns if self.t_first is None else self.t_first
        if t_ns - self.last_hb >= 1_000_000_000:
            link.heartbeat()
            self.last_hb = t_ns
        if fp.pose is not None:
            link.send_vision_position_estimate(t_ns, fp.pose.T_W_B, fp.pose.cov)
        if self.plan is not None:
            t_rel = self.plan.t_ns[0] + (t_ns - self.t_first)
            k = min(int(np.searchsorted(self.plan.t_ns, t_rel)), len(self.plan) - 1)
            link.send_position_setpoint(self.plan.p_W_B[k], 0.0)
        link.poll()

    def close(self) -> MavlinkCounts:
        s = self.link.stats
        self.link.close()
        return MavlinkCounts(
            url=self.url, sent=dict(s.sent), received=dict(s.received), bad_packets=s.bad_packets
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class MavlinkCounts:
    """What the companion link sent and received, by message name."""

    url: str
    sent: Mapping[str, int]
    received: Mapping[str, int]
    bad_packets: int


@dataclass(frozen=True, slots=True, kw_only=True)
class MarkersStats:
    """What a markers run measured: ``stats.json``; its named numbers are ``metrics.json``."""

    source: str
    time_base: str
    fps: float
    frames: int
    frames_processed: int
    frames_skipped: int
    skipped: tuple[str, ...]  # why, for the first 50
    frames_with_pose: int
    fraction_with_pose: float
    frames_rejected: int
    rejected_by_reason: Mapping[str, int]
    frames_marker_fallback: int  # poses from a board's marker corners (charuco.marker_fallback)
    world_marker_id: int | None
    jitter_rms_mm: float
    jitter_median_mm: float
    detect_ms_median: float
    pose_ms_median: float
    rms_px_median: float
    camera_properties: tuple[CaptureProperty, ...]
    calibration: str
    notes: tuple[str, ...]
    images_written: int
    images_mb: float
    images_not_written: int  # past max_images_mb
    stopped_by: str | None
    unknown_detector_parameters: tuple[str, ...]
    run_dir: Path
    mavlink: MavlinkCounts | None = None  # with --mavlink only

    def as_json(self) -> dict[str, object]:
        """``stats.json``: every field in order (``mavlink`` only with a link)."""
        out: dict[str, object] = {f.name: getattr(self, f.name) for f in fields(self)}
        out["camera_properties"] = [dataclasses.asdict(p) for p in self.camera_properties]
        out["run_dir"] = str(self.run_dir)
        if self.mavlink is None:
            del out["mavlink"]
        else:
            out["mavlink"] = dataclasses.asdict(self.mavlink)
        return out

    def metrics_json(self) -> dict[str, object]:
        """``metrics.json``: the flat named numbers of :data:`METRICS` (NaN written as null),
        ``kind: markers``."""
        return {"kind": "markers", **{k: getattr(self, k) for k in METRICS}}


@dataclass(slots=True)
class _Processed:
    results: list[FramePose] = field(default_factory=list)
    frame_idx: list[int] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    world_id: int | None = None
    n_total: int = 0
    stopped_by: str | None = None


def _expected_frames(cfg: MarkersConfig, frames: FrameSource) -> int | None:
    """How many frames the run will take, when the source knows (or ``max_frames`` says)."""
    if cfg.max_frames is None:
        return frames.total
    return min(frames.total or cfg.max_frames, cfg.max_frames)


def _process(
    cfg: MarkersConfig,
    frames: FrameSource,
    camera: PinholeCamera,
    det_params: cv2.aruco.DetectorParameters,
    overlay: _Overlay,
    companion: _Companion | None,
    progress: Progress | None,
    poses_csv: CsvAppender,
) -> _Processed:
    """Every frame through the pipeline, the overlay and the link; each pipeline result is a
    row of ``poses_csv`` at once (flushed: a run stopped half way keeps what it made)."""
    out = _Processed(world_id=cfg.marker_id)
    pipeline: MarkerPipeline | None = None
    if cfg.target != "marker" or cfg.marker_id is not None:
        pipeline = MarkerPipeline(
            camera,
            cfg.marker_map(),
            cfg.T_B_C(),
            params=det_params,
            prior_sigma_px=cfg.prior_sigma_px,
            max_rms_px=cfg.max_rms_px,
            charuco_min_markers=cfg.charuco.min_markers,
            board_marker_fallback=cfg.charuco.marker_fallback,
            fallback_gate=cfg.charuco.fallback_gate(),
        )
    detector = MarkerDetector(get_dictionary(cfg.dictionary), det_params)
    total = _expected_frames(cfg, frames)
    n_poses = 0
    try:
        for fr in frames:
            if (cfg.max_frames is not None and fr.index >= cfg.max_frames) or overlay.stopped:
                break
            out.n_total += 1
            if fr.image is None:
                out.skipped.append(f"frame {fr.index}: {fr.error}")
            else:
                probe = None
                if pipeline is None:
                    # One marker is the world: the lowest id of the first frame that shows any.
                    probe = detector.detect(fr.image)
                    if len(probe):
                        out.world_id = int(probe.ids.min())
                        pipeline = MarkerPipeline(
                            camera,
                            cfg.marker_map(out.world_id),
                            cfg.T_B_C(),
                            params=det_params,
                            prior_sigma_px=cfg.prior_sigma_px,
                            max_rms_px=cfg.max_rms_px,
                        )
                fp = pipeline.process(fr.image, fr.t_ns) if pipeline is not None else None
                if fp is not None:
                    out.results.append(fp)
                    poses_csv.append(_pose_row(fr.index, fp))
                    out.frame_idx.append(fr.index)
                    n_poses += fp.pose is not None
                    if companion is not None:
                        companion.send(fr.t_ns, fp)
                overlay.frame(fr.index, fr.image, fp, probe)
            if progress:
                progress(fr.index + 1, total or 0, f"{n_poses} poses")
    except KeyboardInterrupt:
        if frames.kind != "camera":
            raise  # a file stopped half way: the run folder says interrupted, its rows kept
        out.stopped_by = "interrupt (Ctrl-C)"  # how a live camera's run ends: it is complete
    if overlay.stopped:
        out.stopped_by = "window (q or Esc)"
    return out


def run_markers(
    cfg: MarkersConfig,
    source: str,
    out: Path,
    *,
    progress: Progress | None = None,
    mavlink: str | None = None,
    allow_remote: bool = False,
    setpoints: Path | None = None,
    open_camera: Callable[[int], Any] = cv2.VideoCapture,
    notify: Notify | None = None,
) -> MarkersStats:
    """Process every frame of ``source``; write the run folder; return the statistics. With
    ``mavlink``, be thesis 000's companion computer (see :class:`_Companion`). A live camera
    is opened by ``open_camera`` and asked for the configured fps, size and exposure.
    ``notify`` gets the notes for the user during the run (where the images go, and how
    much)."""
    if cfg.camera_file is None:
        raise ConfigError(
            "no camera calibration: give --camera cal.yml (OpenCV YAML) or camera_file in the parameters"
        )
    window = (
        FrameWindow("quadnav markers", "show (--show; the thesis's open_window)")
        if cfg.show
        else None
    )
    camera = read_camera_yaml(cfg.camera_file)
    values = {**(read_opencv_yaml(cfg.detector_file) if cfg.detector_file else {}), **cfg.detector}
    det_params, unknown = detector_parameters(values)
    _check_detector(cfg, det_params)
    with quiet_libraries():
        frames = open_frames(
            source, fps=cfg.fps, request=_capture_request(cfg), open_camera=open_camera
        )
        camera, cal_note = fit_calibration(camera, frames.size or (camera.width, camera.height))
        run_dir = create_run_folder(out, "markers")
        write_text(run_dir / "config.yaml", dump_config(cfg))
        overlay = _Overlay(cfg, run_dir, frames.fps, camera, det_params, window,
                           expected_frames=_expected_frames(cfg, frames), notify=notify)  # fmt: skip
        companion = (
            _Companion(mavlink, setpoints, allow_remote=allow_remote)
            if mavlink is not None
            else None
        )
        try:
            with CsvAppender(run_dir / "poses.csv", POSE_COLUMNS) as poses_csv:
                done = _process(
                    cfg, frames, camera, det_params, overlay, companion, progress, poses_csv
                )
        except BaseException:
            if companion is not None:
                companion.close()
            raise
        finally:
            overlay.close()
    notes = [cal_note] if cal_note else []
    notes += [
        f"{frames.description} did not take {p.name}={p.requested:g} (it reports {p.got:g})"
        for p in frames.properties
        if not p.accepted
    ]
    stats = _statistics(
        cfg,
        frames,
        done,
        calibration=cal_note or f"{camera.width}x{camera.height}, as calibrated",
        notes=tuple(notes),
        images=overlay.images,
        stopped_by=done.stopped_by,
        unknown_detector_parameters=tuple(unknown),
        run_dir=run_dir,
        mavlink=companion.close() if companion is not None else None,
    )
    write_json(run_dir / "stats.json", stats.as_json())
    write_json(run_dir / "metrics.json", stats.metrics_json())
    _write_report(run_dir, cfg, frames, done, stats)
    return stats


def _jitter(pos: np.ndarray, frame_idx: list[int]) -> np.ndarray:
    """The pose noise from frame to frame. A moving camera's smooth motion cancels in the
    second difference p[k+1] - 2 p[k] + p[k-1] of consecutive frames; white noise of sigma
    per axis gives it a variance of 6 sigma^2."""
    fidx = np.array(frame_idx)
    have = np.isfinite(pos[:, 0])
    if len(pos) <= 2:
        return np.zeros(0)
    triple = have[2:] & have[1:-1] & have[:-2] & (fidx[2:] - fidx[:-2] == 2)
    d2 = (pos[2:] - 2 * pos[1:-1] + pos[:-2])[triple]
    return np.asarray(np.linalg.norm(d2, axis=1) / math.sqrt(6.0))


def _median(values: Any) -> float:
    return float(np.median(values)) if len(values) else math.nan


def _statistics(
    cfg: MarkersConfig,
    frames: FrameSource,
    done: _Processed,
    *,
    calibration: str,
    notes: tuple[str, ...],
    images: ImagesOut | None,
    stopped_by: str | None,
    unknown_detector_parameters: tuple[str, ...],
    run_dir: Path,
    mavlink: MavlinkCounts | None,
) -> MarkersStats:
    nan3 = np.full(3, np.nan)
    pos = np.array(
        [r.pose.T_W_B.p_A_B if r.pose is not None else nan3 for r in done.results]
    ).reshape(-1, 3)
    steps = _jitter(pos, done.frame_idx)
    ok = [r for r in done.results if r.pose is not None]
    n_total = done.n_total
    return MarkersStats(
        source=frames.description,
        time_base=_time_base(cfg, frames),
        fps=frames.fps,
        frames=n_total,
        frames_processed=len(done.results),
        frames_skipped=len(done.skipped),
        skipped=tuple(done.skipped[:50]),
        frames_with_pose=len(ok),
        fraction_with_pose=len(ok) / n_total if n_total else 0.0,
        frames_rejected=sum(r.pose is None and r.reason != "no_target" for r in done.results),
        rejected_by_reason=dict(Counter(r.reason for r in done.results if r.pose is None)),
        frames_marker_fallback=sum(r.fallback for r in ok),
        world_marker_id=done.world_id if cfg.target == "marker" else None,
        jitter_rms_mm=float(np.sqrt(np.mean(steps**2)) * 1e3) if len(steps) else math.nan,
        jitter_median_mm=_median(steps) * 1e3,
        detect_ms_median=_median([r.detect_ms for r in done.results]),
        pose_ms_median=_median([r.pose_ms for r in ok]),
        rms_px_median=_median([r.rms_px for r in ok]),
        camera_properties=frames.properties,
        calibration=calibration,
        notes=notes,
        images_written=images.frames if images is not None else 0,
        images_mb=images.bytes / 1e6 if images is not None else 0.0,
        images_not_written=images.refused if images is not None else 0,
        stopped_by=stopped_by,
        unknown_detector_parameters=unknown_detector_parameters,
        run_dir=run_dir,
        mavlink=mavlink,
    )


#: The named numbers of a markers run that ``quadnav eval --table`` puts side by side.
METRICS = ("frames", "frames_processed", "frames_skipped", "frames_with_pose",
           "fraction_with_pose", "frames_rejected", "jitter_rms_mm", "jitter_median_mm", "detect_ms_median",
           "pose_ms_median", "rms_px_median", "fps")  # fmt: skip


def _write_report(
    run_dir: Path, cfg: MarkersConfig, frames: FrameSource, done: _Processed, stats: MarkersStats
) -> None:
    t = np.array([r.t_ns for r in done.results], dtype=np.int64)
    pos = np.array(
        [r.pose.T_W_B.p_A_B if r.pose is not None else np.full(3, np.nan) for r in done.results]
    ).reshape(-1, 3)
    det_ms = np.array([r.detect_ms for r in done.results])
    pose_ms = np.array([r.pose_ms for r in done.results if r.pose is not None])
    images = _plots(run_dir, t, pos, det_ms, pose_ms)
    hidden = ("skipped", "run_dir", "unknown_detector_parameters", "camera_properties", "mavlink", "notes")  # fmt: skip
    rows = [[k, v] for k, v in stats.as_json().items() if k not in hidden]
    rows += [
        [f"camera {p.name}", f"asked {p.requested:g}, got {p.got:g}"]
        for p in stats.camera_properties
    ]
    write_report(
        run_dir / "report.html",
        title=f"markers: {frames.description}",
        sections=[
            ReportSection(
                "Statistics", tables=[ReportTable("per run", ["measure", "value"], rows)]
            ),
            ReportSection("Plots", images=images),
            ReportSection("Configuration", code=dump_config(cfg)),
        ],
    )


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


def _check_detector(cfg: MarkersConfig, det_params: cv2.aruco.DetectorParameters) -> None:
    """OpenCV checks detector parameters only when it detects: try them on a blank image, so
    a bad value is a one-line error naming the user's key before any work."""
    try:
        detector = cv2.aruco.ArucoDetector(get_dictionary(cfg.dictionary), det_params)
        detector.detectMarkers(np.zeros((16, 16), np.uint8))
    except cv2.error as exc:
        where = (
            f"detector (or detector_file {cfg.detector_file})" if cfg.detector_file else "detector"
        )
        raise ConfigError(
            f"{where}: OpenCV refuses these parameters ({opencv_error_text(exc)})"
        ) from None
