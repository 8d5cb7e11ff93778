"""A visual-inertial odometry run (``quadnav vio DATASET``) into a run folder.

The dataset's IMU samples and one camera's images go, in time order, into anything that
satisfies :class:`quadnav.vio.VisualOdometry`. The folder holds ``estimate.tum`` (the body's
pose at each camera frame with an estimate, for evo), ``groundtruth.tum`` (when the dataset has
one), ``metrics.json`` (:class:`quadnav.eval.vio_metrics.VioMetrics` with the run's timing),
``events.jsonl`` (initialisation, failures, re-initialisations and rejected images as they
happen), ``timing.json``, ``plots/``, ``tracks.mp4`` (the tracked features), ``report.html`` and
the ``config.yaml`` used. A corrupt image is rejected and counted; the run goes on.
"""

from __future__ import annotations

import dataclasses
import shutil
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel

from quadnav.errors import ConfigError, EvalError, GeometryError, IoError, SampleError
from quadnav.eval.associate import associate
from quadnav.eval.na import Metric, fmt_metric, na
from quadnav.eval.vio_metrics import RunCounts, VioMetrics, vio_metrics
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.config import load_config
from quadnav.io.datasets import VisualInertialDataset, open_dataset
from quadnav.io.frames import VideoOut
from quadnav.io.run_folder import append_jsonl, create_run_folder, write_json, write_text
from quadnav.io.trajectory_io import write_tum
from quadnav.messages import ImageFrame, ImuSample
from quadnav.rig import Rig
from quadnav.units import ns_to_s, s_to_ns
from quadnav.vio import FrameFeatures, VioEvent, VioState, VisualOdometry
from quadnav.vision.track_video import draw_tracks
from quadnav.vision.tracking import FrameCounts, TrackedFrame, as_grey

__all__ = [
    "EstimatorFactory",
    "VioRequest",
    "VioRun",
    "VioRunOptions",
    "VioTiming",
    "check_request",
    "check_vio_rig",
    "dataset_cache_folder",
    "resolve_dataset",
    "resolve_vio_config",
    "run_vio",
    "run_vio_source",
    "write_vio_outputs",
]

M = TypeVar("M", bound=BaseModel)
Progress = Callable[[int, int, str], None]
#: Makes the estimator of a run from the rig it runs on (the dataset's or a config file's).
EstimatorFactory = Callable[[Rig], VisualOdometry]
FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class VioRunOptions:
    """What part of the dataset a run covers and what it writes: ``camera`` (its name in the
    rig), ``start_s`` and ``duration_s`` (from the camera's first image; None: to its last),
    ``imu_lead_s`` the IMU fed before the first image (a static start looks at it),
    ``video`` every ``video_every`` frames, ``drift_first_s`` the span the final drift aligns
    on, ``t_max_diff_s`` how far an estimate may be from a ground-truth sample to be scored."""

    camera: str = "cam0"
    start_s: float = 0.0
    duration_s: float | None = None
    imu_lead_s: float = 1.0
    video: bool = True
    video_every: int = 1
    drift_first_s: float = 2.0
    t_max_diff_s: float = 0.02


@dataclass(frozen=True, slots=True, kw_only=True)
class VioTiming:
    """Where the run's time went: per stage (the estimator's own ``timing()``), the estimator
    as a whole (every ``push_imu`` and ``push_image``), frames per second of that, and the
    run's wall time (reading images, writing the video and files included)."""

    frames: int
    estimator_s: float
    frames_per_s: float
    wall_s: float
    stage_ms_per_call: Mapping[str, float]
    stage_ms_per_frame: Mapping[str, float]
    stage_calls: Mapping[str, int]


@dataclass(frozen=True, slots=True, kw_only=True)
class VioRun:
    """A finished run: its folder, what it measured, when it went wrong and how fast it was."""

    run_dir: Path
    dataset: str
    camera: str
    metrics: VioMetrics
    timing: VioTiming
    events: tuple[VioEvent, ...]
    notes: tuple[str, ...] = ()

    def as_json(self) -> dict[str, object]:
        return {
            "dataset": self.dataset, "camera": self.camera,
            **dataclasses.asdict(self.metrics), "timing": dataclasses.asdict(self.timing),
            "notes": list(self.notes),
        }  # fmt: skip


# -- what a run reads ---------------------------------------------------------------------------


def dataset_cache_folder(root: Path, name: str, rig: str, seed: int, duration_s: float) -> Path:
    """Where a built-in sequence made for a run is kept: keyed by sequence, rig, seed and
    length, so that the same run reuses it and a different one does not."""
    return Path(root) / "datasets" / f"{name}_{rig}_s{seed}_{duration_s:g}s"


def _make_sequence(
    name: str,
    *,
    rig: str,
    seed: int,
    duration_s: float,
    cache_root: Path,
    progress: Progress | None,
) -> Path:
    from quadnav.experiments.datasets import make_dataset, sequence_spec

    # Ideal sensors, as these sequences were made before the dataset maker's realistic default
    # (issue 22, item 6): realistic ones are `quadnav dataset make`'s, run as `quadnav vio DIR`.
    fields = {"rig": rig, "seed": seed, "duration_s": duration_s, "sensors": "ideal"}
    spec = sequence_spec(name, fields)
    folder = dataset_cache_folder(cache_root, name, rig, seed, spec.duration_s)
    if (folder / "dataset.json").is_file():
        return folder  # made before, to the end (the manifest is written last)
    if folder.exists():
        shutil.rmtree(folder)  # a make that was stopped between the images and the manifest
    make_dataset(spec, folder, name=name, progress=progress)
    return folder


def resolve_dataset(
    source: str,
    *,
    seed: int = 0,
    rig: str = "euroc_mono",
    duration_s: float | None = None,
    start_s: float = 0.0,
    cache_root: Path = Path("runs"),
    calibration: Path | None = None,
    progress: Progress | None = None,
) -> VisualInertialDataset:
    """The dataset a run reads: a folder or bag ``open_dataset`` knows (``calibration``, a
    Kalibr camchain or an EuRoC folder, replacing its own), or a built-in sequence made (once)
    for ``seed`` and ``rig`` under ``cache_root/datasets``, as long as the run needs
    (``start_s + duration_s``; the whole sequence without a duration)."""
    from quadnav.experiments.datasets import SEQUENCES

    path = Path(source)
    if path.exists() or source not in SEQUENCES:
        if not path.exists():
            raise IoError(
                f"DATASET {source!r}: no such file or folder, and not a built-in sequence "
                f"({', '.join(SEQUENCES)})"
            )
        return open_dataset(path, calibration=calibration)
    length = SEQUENCES[source].duration_s if duration_s is None else start_s + duration_s
    folder = _make_sequence(
        source, rig=rig, seed=seed, duration_s=length, cache_root=cache_root, progress=progress
    )
    return open_dataset(folder)


def _is_vins_yaml(path: Path) -> bool:
    try:
        head = path.read_text(encoding="utf-8", errors="replace")[:4000]
    except OSError as exc:
        raise ConfigError(f"--config {path}: cannot be read ({exc.strerror})") from None
    return head.lstrip().startswith("%YAML") or "extrinsicRotation" in head


def resolve_vio_config(
    model: type[M],
    config: Path | None,
    overrides: Iterable[str],
    dataset_rig: Rig,
    *,
    camera: str = "cam0",
) -> tuple[M, Rig]:
    """The estimator's settings (``model``, e.g. ``VioConfig``) and the rig it runs on: from
    VINS-Mono's YAML (its camera, extrinsic and IMU noise replace the dataset's calibration;
    its front end, ``g_norm``, ``estimate_td`` and ``td`` set those fields), from our own YAML
    of ``model``'s fields (unknown keys refused), or the defaults on the dataset's calibration."""
    if config is not None and not config.is_file():
        raise ConfigError(f"--config {config}: no such file")
    rig = dataset_rig
    if config is not None and _is_vins_yaml(config):
        from quadnav.io.vins_config import read_vins_config

        cam = dataset_rig.camera(camera) if camera in dataset_rig.camera_names else None
        imu_rate = dataset_rig.imu.rate_hz if dataset_rig.imu is not None else 200.0
        vins = read_vins_config(
            config, imu_rate_hz=imu_rate, camera_rate_hz=cam.rate_hz if cam else 20.0
        )
        only = dataclasses.replace(vins.rig.cameras[0], name=camera)  # the camera it describes
        rig = dataclasses.replace(vins.rig, cameras=(only,))
        known = model.model_fields
        values: dict[str, object] = {
            "tracker": vins.tracker.model_dump(), "g_norm": vins.g_norm_m_s2,
            "estimate_td": vins.estimate_td, "td_s": ns_to_s(rig.cameras[0].time_offset_ns),
        }  # fmt: skip
        base = {k: v for k, v in values.items() if k in known}
        return load_config(model, None, overrides, base=base), rig
    return load_config(model, config, overrides), rig


# -- the run ------------------------------------------------------------------------------------


def check_vio_rig(rig: Rig, source: str) -> None:
    """Refuse a rig VIO cannot run on: no IMU, or no IMU noise (what a bag without its
    calibration gives, whose camera extrinsic is then unknown too)."""
    n = rig.imu.noise if rig.imu is not None else None
    if n is None or n.gyro_noise_density <= 0.0 or n.accel_noise_density <= 0.0:
        raise ConfigError(
            f"DATASET {source}: its files give no IMU noise (a bag without calibration?): "
            "give --calibration (a Kalibr camchain or an EuRoC folder) or --config "
            "(VINS-Mono's YAML)"
        )


def _span_frames(
    dataset: VisualInertialDataset, options: VioRunOptions
) -> tuple[int, int, list[ImageFrame]]:
    if options.camera not in dataset.rig.camera_names:
        raise ConfigError(
            f"--camera {options.camera!r}: the dataset's cameras are "
            f"{', '.join(dataset.rig.camera_names)}"
        )
    if len(dataset.imu) == 0:
        raise ConfigError(f"{dataset.root}: the dataset has no IMU samples: VIO needs them")
    frames = dataset.frames_of(options.camera)
    if not frames:
        raise ConfigError(f"{dataset.root}: camera {options.camera} has no images")
    t0 = frames[0].t_ns + s_to_ns(options.start_s)
    t1 = t0 + s_to_ns(options.duration_s) if options.duration_s is not None else frames[-1].t_ns
    chosen = [f for f in frames if t0 <= f.t_ns <= t1]
    if not chosen:
        raise ConfigError(
            f"--start {options.start_s:g} s / --duration: no image of {options.camera} "
            f"in that span of {dataset.duration_s:.1f} s"
        )
    t0, t1 = chosen[0].t_ns, chosen[-1].t_ns
    return t0, t1, chosen


def _stream(
    dataset: VisualInertialDataset, camera: str, t0: int, t1: int, imu_lead_ns: int
) -> Iterator[ImageFrame | ImuSample]:
    """The camera's frames in ``[t0, t1]`` and the IMU from ``imu_lead_ns`` before ``t0``."""
    for s in dataset.stream():
        if s.t_ns < t0 - imu_lead_ns or (s.t_ns < t0 and not isinstance(s, ImuSample)):
            continue
        if s.t_ns > t1:
            return
        if isinstance(s, ImuSample) or s.camera == camera:
            yield s


@dataclass(slots=True)
class _Tracks:
    """The features drawn in ``tracks.mp4``: each id's track length so far, the last frame."""

    video: VideoOut | None
    every: int
    lengths: dict[int, int] = field(default_factory=dict)
    previous: TrackedFrame | None = None

    def add(self, k: int, image: NDArray[np.uint8], f: FrameFeatures | None, text: str) -> None:
        if f is None:
            self.previous = None
            if self.video is not None and k % self.every == 0:
                grey = as_grey(image)
                self.video.write(_caption(np.asarray(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)), text))
            return
        ids = np.asarray(f.ids, dtype=np.int64)
        n = np.array([self.lengths.get(int(i), 0) + 1 for i in ids], dtype=np.int64)
        self.lengths = dict(zip(ids.tolist(), n.tolist(), strict=True))
        zero = FrameCounts(
            previous=0, tracked=0, lost_klt=0, lost_border=0, lost_fb=0, lost_ransac=0,
            lost_spacing=0, new=0,
        )  # fmt: skip
        frame = TrackedFrame(
            t_ns=f.t_ns, ids=ids, pixels=f.uv_px, pixels_undistorted=f.uv_px,
            track_lengths=n, is_new=n == 1, counts=zero,
        )  # fmt: skip
        if self.video is not None and k % self.every == 0:
            self.video.write(_caption(draw_tracks(image, frame, self.previous), text))
        self.previous = frame


def _caption(image: NDArray[np.uint8], text: str) -> NDArray[np.uint8]:
    out = np.ascontiguousarray(image)
    cv2.putText(out, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 255, 255), 1, cv2.LINE_AA)
    return out


@dataclass(slots=True)
class _Record:
    """What the loop collects: the camera-rate states, the counts, the events written."""

    states: list[VioState] = field(default_factory=list)
    frames: int = 0
    rejected: int = 0
    events_written: int = 0
    estimator_s: float = 0.0
    first_frame_ns: int | None = None


def _event_json(e: VioEvent, t0: int) -> dict[str, object]:
    return {"t_ns": e.t_ns, "t_s": ns_to_s(e.t_ns - t0), "kind": e.kind, "detail": e.detail}


def _flush_events(vio: VisualOdometry, rec: _Record, path: Path, t0: int) -> None:
    events = vio.events
    for e in events[rec.events_written :]:
        append_jsonl(path, _event_json(e, t0))
    rec.events_written = len(events)


def _image_of(frame: ImageFrame, rec: _Record, events: Path, t0: int) -> NDArray[np.uint8] | None:
    try:
        return frame.image()
    except SampleError as exc:
        rec.rejected += 1
        append_jsonl(
            events,
            {"t_ns": frame.t_ns, "t_s": ns_to_s(frame.t_ns - t0), "kind": "rejected_image",
             "detail": str(exc)},
        )  # fmt: skip
        return None


def _status(state: VioState | None, t_s: float, rec: _Record) -> str:
    if state is None:
        return f"{t_s:6.2f} s  no estimate"
    return f"{t_s:6.2f} s  {state.status}  {state.tracked} tracked  reset {state.reset_counter}"


def _loop(
    vio: VisualOdometry,
    stream: Iterator[ImageFrame | ImuSample],
    n_frames: int,
    run_dir: Path,
    tracks: _Tracks,
    t0: int,
    progress: Progress | None,
    rec: _Record,
) -> None:
    """Feed the stream to ``vio``, filling ``rec`` (kept as far as it got on an interrupt)."""
    events = run_dir / "events.jsonl"
    events.touch()
    for s in stream:
        if isinstance(s, ImuSample):
            tic = time.perf_counter()
            vio.push_imu(s)
            rec.estimator_s += time.perf_counter() - tic
            continue
        image = _image_of(s, rec, events, t0)
        if image is None:
            continue
        rec.first_frame_ns = s.t_ns if rec.first_frame_ns is None else rec.first_frame_ns
        tic = time.perf_counter()
        state = vio.push_image(s.t_ns, image)
        rec.estimator_s += time.perf_counter() - tic
        rec.frames += 1
        if state is not None:
            rec.states.append(state)
        _flush_events(vio, rec, events, t0)
        tracks.add(
            rec.frames - 1, image, vio.last_features, _status(state, ns_to_s(s.t_ns - t0), rec)
        )
        if progress is not None:
            progress(rec.frames + rec.rejected, n_frames, f"{ns_to_s(s.t_ns - t0):.1f} s")


def _estimate(states: list[VioState]) -> tuple[Trajectory, FloatArray]:
    """The camera-rate estimate (time-ordered, one pose per stamp) and its pose covariances."""
    kept: dict[int, VioState] = {}
    for st in states:
        kept[st.t_ns] = st  # a repeated stamp: the later state
    ordered = [kept[t] for t in sorted(kept)]
    t = np.array([s.t_ns for s in ordered], dtype=np.int64)
    p = np.array([s.T_W_B.p_A_B for s in ordered]).reshape(-1, 3)
    q = np.array([s.T_W_B.R_A_B.as_quat() for s in ordered]).reshape(-1, 4)
    cov = np.array([s.cov_pose for s in ordered], dtype=np.float64).reshape(-1, 6, 6)
    return Trajectory(t_ns=t, p_W_B=p, q_W_B_xyzw=q, name="vio"), cov


def _timing(vio: VisualOdometry, rec: _Record, wall_s: float) -> VioTiming:
    stages = vio.timing().stages
    frames = max(rec.frames, 1)
    return VioTiming(
        frames=rec.frames, estimator_s=rec.estimator_s,
        frames_per_s=rec.frames / rec.estimator_s if rec.estimator_s > 0 else 0.0,
        wall_s=wall_s, stage_ms_per_call=vio.timing().per_call_ms(),
        stage_ms_per_frame={name: 1e3 * s / frames for name, s, _ in stages},
        stage_calls={name: n for name, _, n in stages},
    )  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class _Scored:
    """The estimate and the ground truth matched to it (None without one), for the metrics
    and the plots; ``truth`` is the ground truth over the run's span."""

    est: Trajectory
    cov: FloatArray
    matched_truth: Trajectory | None = None
    matched_est: Trajectory | None = None
    matched_cov: FloatArray | None = None
    truth: Trajectory | None = None
    note: str = ""


def _score(
    dataset: VisualInertialDataset,
    est: Trajectory,
    cov: FloatArray,
    t0: int,
    t1: int,
    opt: VioRunOptions,
) -> _Scored:
    gt = dataset.groundtruth
    if gt is None:
        return _Scored(est=est, cov=cov)
    tr = gt.trajectory
    truth = tr.select(np.flatnonzero((tr.t_ns >= t0) & (tr.t_ns <= t1)))
    if len(est) == 0 or len(truth) < 2:
        note = "no estimate to score" if len(est) == 0 else "no ground truth in the run's span"
        return _Scored(est=est, cov=cov, truth=truth if len(truth) else None, note=note)
    try:
        ref_m, est_m = associate(truth, est, t_max_diff_s=opt.t_max_diff_s, interpolate=True)
    except EvalError as exc:
        return _Scored(est=est, cov=cov, truth=truth, note=str(exc))
    idx = np.searchsorted(est.t_ns, est_m.t_ns)
    return _Scored(
        est=est, cov=cov, matched_truth=ref_m, matched_est=est_m, matched_cov=cov[idx], truth=truth
    )


def _counts(rec: _Record, vio: VisualOdometry, t0: int) -> RunCounts:
    kinds = [e.kind for e in vio.events]
    first = rec.states[0].t_ns if rec.states else None
    after: Metric = (
        ns_to_s(first - (rec.first_frame_ns or t0))
        if first is not None
        else na("never initialised")
    )
    return RunCounts(
        frames=rec.frames + rec.rejected, failures=kinds.count("failure"),
        reinitializations=kinds.count("reinitialized"), rejected_images=rec.rejected,
        initialized_after_s=after,
    )  # fmt: skip


def run_vio(
    dataset: VisualInertialDataset,
    rig: Rig,
    make_estimator: EstimatorFactory,
    out: Path,
    *,
    config_text: str = "",
    options: VioRunOptions | None = None,
    name: str = "",
    progress: Progress | None = None,
) -> VioRun:
    """Run the estimator ``make_estimator(rig)`` over ``dataset``'s IMU and one camera into a
    run folder under ``out`` (see the module); what it measured."""
    opt = options or VioRunOptions()
    start = time.perf_counter()
    t0, t1, frames = _span_frames(dataset, opt)
    vio = make_estimator(rig)
    run_dir = create_run_folder(out, f"vio_{name or dataset.name}")
    write_text(run_dir / "config.yaml", config_text)
    video = (
        VideoOut(run_dir / "tracks.mp4", rig.camera(opt.camera).rate_hz / opt.video_every)
        if opt.video
        else None
    )
    tracks = _Tracks(video=video, every=opt.video_every)
    rec = _Record()
    try:
        _loop(
            vio,
            _stream(dataset, opt.camera, t0, t1, s_to_ns(opt.imu_lead_s)),
            len(frames),
            run_dir,
            tracks,
            t0,
            progress,
            rec,
        )
    finally:
        if video is not None:
            video.close()
        est, cov = _estimate(rec.states)
        write_tum(run_dir / "estimate.tum", est)
    return _finish(dataset, vio, rec, run_dir, est, cov, (t0, t1), opt, time.perf_counter() - start)


def _finish(
    dataset: VisualInertialDataset,
    vio: VisualOdometry,
    rec: _Record,
    run_dir: Path,
    est: Trajectory,
    cov: FloatArray,
    span: tuple[int, int],
    opt: VioRunOptions,
    wall_s: float,
) -> VioRun:
    scored = _score(dataset, est, cov, span[0], span[1], opt)
    if scored.truth is not None:
        write_tum(run_dir / "groundtruth.tum", scored.truth)
    metrics = vio_metrics(
        scored.matched_truth, scored.matched_est if scored.matched_est is not None else est,
        _counts(rec, vio, span[0]), cov_pose=scored.matched_cov, drift_first_s=opt.drift_first_s,
        unscored=scored.note or "the dataset has no ground truth",
    )  # fmt: skip
    issues = dataset.issues.for_cameras([opt.camera])  # not those of a camera left unused
    notes = [n for n in (scored.note, issues.summary() if issues else "") if n]
    run = VioRun(
        run_dir=run_dir, dataset=dataset.name, camera=opt.camera, metrics=metrics,
        timing=_timing(vio, rec, wall_s), events=vio.events, notes=tuple(notes),
    )  # fmt: skip
    write_json(run_dir / "timing.json", dataclasses.asdict(run.timing))
    write_json(run_dir / "metrics.json", run.as_json())
    write_vio_outputs(run, scored.matched_truth, scored.matched_est, scored.truth, est)
    return run


# -- plots and report ---------------------------------------------------------------------------


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _plot_path(path: Path, truth: Trajectory | None, est: Trajectory, t0_ns: int) -> Path:
    """Top view and height against time: the estimate (4-DoF aligned when there is a truth)
    and the ground truth dashed."""
    plt = _pyplot()
    fig, (top, up) = plt.subplots(1, 2, figsize=(14, 5.5), constrained_layout=True)
    for tr, style, label in ((truth, "--", "ground truth"), (est, "-", "VIO")):
        if tr is None or len(tr) == 0:
            continue
        top.plot(tr.p_W_B[:, 0], tr.p_W_B[:, 1], style, lw=1.2, label=label)
        up.plot((tr.t_ns - t0_ns) * 1e-9, tr.p_W_B[:, 2], style, lw=1.2, label=label)
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


def _plot_timing(path: Path, timing: VioTiming) -> Path:
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


def _write_plots(
    run: VioRun, ref: Trajectory | None, est_m: Trajectory | None, truth: Trajectory | None,
    est: Trajectory,
) -> list[Path]:  # fmt: skip
    from quadnav.eval.align import align
    from quadnav.eval.metrics import ape
    from quadnav.eval.plots import plot_errors

    plots = run.run_dir / "plots"
    t0 = int(truth.t_ns[0]) if truth is not None else int(est.t_ns[0]) if len(est) else 0
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
    if run.timing.stage_ms_per_frame:
        images.append(_plot_timing(plots / "timing.png", run.timing))
    return images


def _metric_rows(m: VioMetrics) -> list[list[object]]:
    """The report's metrics, numbers to 4 significant digits (``metrics.json`` keeps them all)."""

    def cell(v: object, key: str | None = None) -> str:
        value = getattr(v, key) if key is not None and not isinstance(v, str) else v
        return fmt_metric(value, ".4g")

    return [
        ["APE 4-DoF RMSE (m)", cell(m.ape_4dof, "rmse_m")],
        ["APE 4-DoF median / max (m)", f"{cell(m.ape_4dof, 'median_m')} / {cell(m.ape_4dof, 'max_m')}"],
        ["APE SE(3) RMSE (m)", cell(m.ape_se3, "rmse_m")],
        ["APE Sim(3) RMSE (m), scale", f"{cell(m.ape_sim3, 'rmse_m')}, {cell(m.ape_sim3, 'scale')}"],
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
        ["failures, re-initialisations", f"{m.failures}, {m.reinitializations}"],
        ["rejected images", m.rejected_images],
    ]  # fmt: skip


def write_vio_outputs(
    run: VioRun, ref: Trajectory | None, est_m: Trajectory | None, truth: Trajectory | None,
    est: Trajectory,
) -> None:  # fmt: skip
    """The plots and ``report.html`` of a finished run."""
    from quadnav.eval.report import ReportSection, ReportTable, write_report

    try:
        images = _write_plots(run, ref, est_m, truth, est)
    except OSError as exc:  # matplotlib and PIL raise it as it is (a full disk, say)
        where = exc.filename or run.run_dir / "plots"
        raise IoError(f"cannot write {where}: {exc.strerror or exc}") from None
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
                        "against the ground truth", ["metric", "value"], _metric_rows(run.metrics)
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


# -- the command's request ----------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class VioRequest:
    """What ``quadnav vio`` was asked: the datasets (folders, bags or built-in sequence names),
    the estimator's configuration file and ``--set`` overrides, the span and outputs, the seed
    (``seeds`` for a study), the rig a built-in sequence is made with, the runs' folder."""

    sources: tuple[str, ...]
    config: Path | None = None
    overrides: tuple[str, ...] = ()
    options: VioRunOptions = field(default_factory=VioRunOptions)
    seed: int = 0
    seeds: tuple[int, ...] | None = None
    rig: str = "euroc_mono"
    out: Path = Path("runs")
    calibration: Path | None = None


def check_request(request: VioRequest) -> None:
    """Refuse a bad configuration, ``--set``, rig or ``--out`` before any dataset is read or
    made."""
    from quadnav.rig import rig_named
    from quadnav.vio import VioConfig

    if request.out.exists() and not request.out.is_dir():
        raise ConfigError(f"--out {request.out}: is a file, not a folder")
    try:
        rig = rig_named(request.rig)
    except GeometryError as exc:
        raise ConfigError(f"--rig: {exc}") from None
    resolve_vio_config(VioConfig, request.config, request.overrides, rig)


def run_vio_source(
    request: VioRequest, source: str, seed: int, out: Path, progress: Progress | None = None
) -> VioRun:
    """One run of ``quadnav vio``: the dataset, the configuration on its rig, VINS-Mono-class
    :class:`quadnav.vio.VioEstimator` over it, into a run folder under ``out``."""
    from quadnav.io.config import dump_config
    from quadnav.vio import VioConfig, VioEstimator

    opt = request.options
    dataset = resolve_dataset(
        source, seed=seed, rig=request.rig, duration_s=opt.duration_s, start_s=opt.start_s,
        cache_root=request.out, calibration=request.calibration, progress=progress,
    )  # fmt: skip
    cfg, rig = resolve_vio_config(
        VioConfig, request.config, request.overrides, dataset.rig, camera=opt.camera
    )
    check_vio_rig(rig, source)
    text = f"# dataset: {dataset.root}\n# rig: {rig.name}\n{dump_config(cfg)}"
    name = Path(source).name if Path(source).exists() else f"{source}_s{seed}"
    return run_vio(
        dataset, rig, lambda r: VioEstimator(r, cfg, camera=opt.camera), out,
        config_text=text, options=opt, name=name, progress=progress,
    )  # fmt: skip
