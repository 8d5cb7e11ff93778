"""One run of any visual odometry (the VIO now, the SLAM next) over any visual-inertial dataset
into a run folder: ``quadnav vio DATASET`` and the commands after it call this, with the
estimator they build.

The dataset's IMU samples and the frames of the cameras the estimator uses go, in time order,
into anything that satisfies :class:`quadnav.odometry.VisualOdometry` through its one ``push``.
The folder holds ``estimate.tum`` (the body's pose at each camera frame with an estimate, for
evo), ``keyframes.tum`` (the keyframes the odometry published, at their final estimates),
``groundtruth.tum`` (when the dataset has one), ``metrics.json``
(:class:`quadnav.eval.vio_metrics.VioMetrics` with the run's timing), ``events.jsonl``
(initialisation, failures, re-initialisations and rejected images as they happen),
``timing.json``, ``plots/``, ``tracks.mp4`` (the tracked features), ``report.html`` and the
``config.yaml`` used. A corrupt image is rejected and counted; the run goes on.
"""

from __future__ import annotations

import dataclasses
import shutil
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import ConfigError, EvalError, IoError, SampleError
from quadnav.eval.associate import associate
from quadnav.eval.na import Metric, na
from quadnav.eval.vio_metrics import RunCounts, VioMetrics, ape_summary, vio_metrics
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.datasets import VisualInertialDataset, open_dataset
from quadnav.io.frames import VideoOut
from quadnav.io.run_folder import append_jsonl, create_run_folder, write_json, write_text
from quadnav.io.trajectory_io import write_tum
from quadnav.messages import ImageFrame, ImuSample
from quadnav.odometry import (
    FrameFeatures,
    KeyframeRecord,
    OdometryEvent,
    OdometryState,
    OnlineCalibration,
    RefinedTrajectory,
    VisualOdometry,
)
from quadnav.rig import Rig
from quadnav.units import ns_to_s, s_to_ns
from quadnav.vision.track_video import draw_tracks
from quadnav.vision.tracking import FrameCounts, TrackedFrame, as_grey

__all__ = [
    "EstimatorFactory",
    "OdometryObserver",
    "OdometryRun",
    "OdometryRunOptions",
    "OdometryTiming",
    "Progress",
    "dataset_cache_folder",
    "resolve_dataset",
    "run_odometry",
]

Progress = Callable[[int, int, str], None]
#: Makes the estimator of a run from the rig it runs on (the dataset's or a config file's).
EstimatorFactory = Callable[[Rig], VisualOdometry]
FloatArray = NDArray[np.float64]


class OdometryObserver(Protocol):
    """What a run shows to anyone watching it (a recording for rerun's viewer): told the rig
    and the frames to come first, then each frame of the run's camera with its pixels and the
    features the odometry tracked in it, each state the run keeps (from whichever sample gave
    it) and the keyframes as they are published; ``finish`` once the folder's files are written
    (the folder not yet marked complete)."""

    def begin(self, rig: Rig, camera: str, n_frames: int) -> None: ...

    def frame(
        self, t_ns: int, image: NDArray[np.uint8], features: FrameFeatures | None
    ) -> None: ...

    def state(self, state: OdometryState) -> None: ...

    def keyframes(self, records: Sequence[KeyframeRecord]) -> None: ...

    def finish(self, run_dir: Path) -> None: ...


@dataclass(frozen=True, slots=True, kw_only=True)
class OdometryRunOptions:
    """What part of the dataset a run covers and what it writes: ``camera`` (its name in the
    rig), ``start_s`` and ``duration_s`` (from the camera's first image; None: to its last),
    ``imu_lead_s`` the IMU fed before the first image (a static start looks at it),
    ``video`` every ``video_every`` frames, ``drift_first_s`` the span the final drift aligns
    on, ``t_max_diff_s`` how far an estimate may be from a ground-truth sample to be scored,
    ``blackout_s`` a camera blackout (start after the first image, length; s): every camera's
    images withheld in it, the IMU not (a test of relocalization); ``save_map`` the folder loop
    closure's map is saved to at the end (with loop closure only)."""

    camera: str = "cam0"
    start_s: float = 0.0
    duration_s: float | None = None
    imu_lead_s: float = 1.0
    video: bool = True
    video_every: int = 1
    drift_first_s: float = 2.0
    t_max_diff_s: float = 0.02
    blackout_s: tuple[float, float] | None = None
    save_map: Path | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class OdometryTiming:
    """Where the run's time went: per stage (the estimator's own ``timing()``), the estimator
    as a whole (every ``push`` and ``keyframes``), frames per second of that, and the
    run's wall time (reading images, writing the video and files included)."""

    frames: int
    estimator_s: float
    frames_per_s: float
    wall_s: float
    stage_ms_per_call: Mapping[str, float]
    stage_ms_per_frame: Mapping[str, float]
    stage_calls: Mapping[str, int]


@dataclass(frozen=True, slots=True, kw_only=True)
class OdometryRun:
    """A finished run: its folder, what it measured, when it went wrong and how fast it was."""

    run_dir: Path
    dataset: str
    camera: str
    metrics: VioMetrics
    timing: OdometryTiming
    events: tuple[OdometryEvent, ...]
    notes: tuple[str, ...] = ()
    #: what the odometry rejected or did not use, by kind (``stereo_unpaired``: a left frame
    #: used as mono for want of its partner)
    input_counts: Mapping[str, int] = field(default_factory=dict)
    #: a SLAM's frames through its final map, scored as the causal estimate is (``ape_se3``,
    #: ``ape_sim3``; ``estimate_final.tum``): not causal (None: not a SLAM, or no truth)
    final: Mapping[str, object] | None = None

    def as_json(self) -> dict[str, object]:
        return {
            "dataset": self.dataset, "camera": self.camera,
            **dataclasses.asdict(self.metrics), "timing": dataclasses.asdict(self.timing),
            "input_counts": dict(self.input_counts), "notes": list(self.notes),
            **({"final": dict(self.final)} if self.final is not None else {}),
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


def check_out_and_rig(out: Path, rig: str) -> Rig:
    """``--out`` (not a file) and ``--rig`` (a rig quadnav knows), checked before anything is
    read or made; the rig."""
    from quadnav.errors import ConfigError, GeometryError
    from quadnav.rig import rig_named

    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: is a file, not a folder")
    try:
        return rig_named(rig)
    except GeometryError as exc:
        raise ConfigError(f"--rig: {exc}") from None


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


# -- the run ------------------------------------------------------------------------------------


def _span_frames(
    dataset: VisualInertialDataset, options: OdometryRunOptions
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


def _blackout_ns(options: OdometryRunOptions, t0: int) -> tuple[int, int] | None:
    if options.blackout_s is None:
        return None
    a, d = options.blackout_s
    return t0 + s_to_ns(a), t0 + s_to_ns(a + d)


def _cameras(vio: VisualOdometry, primary: str) -> tuple[str, ...]:
    """The cameras whose frames the odometry is given: the run's, then the others it uses."""
    return (primary, *[c for c in vio.cameras if c != primary])


def _stream(
    dataset: VisualInertialDataset,
    cameras: tuple[str, ...],
    t0: int,
    t1: int,
    imu_lead_ns: int,
    blackout_ns: tuple[int, int] | None = None,
) -> Iterator[ImageFrame | ImuSample]:
    """The cameras' frames in ``[t0, t1]`` (none in ``blackout_ns``, absolute times) and the IMU
    from ``imu_lead_ns`` before ``t0``."""
    b0, b1 = blackout_ns or (0, -1)
    for s in dataset.stream():
        if s.t_ns < t0 - imu_lead_ns or (s.t_ns < t0 and not isinstance(s, ImuSample)):
            continue
        if s.t_ns > t1:
            return
        if isinstance(s, ImuSample) or (s.camera in cameras and not b0 <= s.t_ns < b1):
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

    #: the camera-rate states, kept compact (see :class:`_States`)
    states: _States = field(default_factory=lambda: _States())
    frames: int = 0
    rejected: int = 0
    events_written: int = 0
    estimator_s: float = 0.0
    first_frame_ns: int | None = None
    #: the published keyframes' stamps and poses (not the records: their keypoints would grow
    #: with the run)
    keyframes: _KeyframePoses = field(default_factory=lambda: _KeyframePoses())
    #: a SLAM's frames through its final map (:class:`~quadnav.odometry.RefinedTrajectory`)
    final: Trajectory | None = None
    #: shown each frame and keyframe (None: nobody watches)
    observer: OdometryObserver | None = None

    def keep(self, state: OdometryState) -> None:
        """A camera-rate state the run writes, shown to the observer."""
        self.states.append(state)
        if self.observer is not None:
            self.observer.state(state)

    def published(self, records: Sequence[KeyframeRecord]) -> None:
        """Keyframes the odometry published: their poses kept, the observer told."""
        self.keyframes.extend(records)
        if self.observer is not None and records:
            self.observer.keyframes(records)


#: Rows a block of :class:`_States` holds (one allocation per 4096 camera frames).
_STATE_BLOCK = 4096
_TRIU = np.triu_indices(6)
_WIDTH = 7 + len(_TRIU[0])  # position (3), quaternion xyzw (4), the covariance's triangle (21)


@dataclass(slots=True)
class _States:
    """The camera-rate states a run writes, in blocks of :data:`_STATE_BLOCK` rows: stamp,
    position, quaternion and the pose covariance's upper triangle, 232 bytes a frame (a row
    array a frame took 474; a state object several kB), 8 MB for 30 minutes at 20 Hz: the
    trajectory it writes, which grows with the run as nothing else the runner keeps does."""

    stamps: list[NDArray[np.int64]] = field(default_factory=list)
    blocks: list[FloatArray] = field(default_factory=list)
    n: int = 0
    first_t_ns: int | None = None

    def append(self, st: OdometryState) -> None:
        if self.first_t_ns is None:
            self.first_t_ns = int(st.t_ns)
        k = self.n % _STATE_BLOCK
        if k == 0:
            self.stamps.append(np.empty(_STATE_BLOCK, dtype=np.int64))
            self.blocks.append(np.empty((_STATE_BLOCK, _WIDTH), dtype=np.float64))
        self.stamps[-1][k] = st.t_ns
        row = self.blocks[-1][k]
        row[:3] = st.T_W_B.p_A_B
        row[3:7] = st.T_W_B.R_A_B.as_quat()
        row[7:] = np.asarray(st.cov_pose, dtype=np.float64)[_TRIU]
        self.n += 1

    def __bool__(self) -> bool:
        return self.n > 0

    def __len__(self) -> int:
        return self.n

    def take(self) -> tuple[NDArray[np.int64], FloatArray]:
        """Stamps (N,) and rows (N, 28: position, quaternion xyzw, the pose covariance's upper
        triangle, :func:`~quadnav.eval.vio_metrics.pose_covariances`' order) in the order
        appended; the blocks are let go (the run's trajectory is not held twice)."""
        t = np.concatenate(self.stamps)[: self.n] if self.n else np.zeros(0, dtype=np.int64)
        rows = np.concatenate(self.blocks)[: self.n] if self.n else np.zeros((0, _WIDTH))
        self.stamps, self.blocks = [], []
        return t, rows


@dataclass(slots=True)
class _KeyframePoses:
    rows: dict[int, tuple[FloatArray, FloatArray]] = field(default_factory=dict)

    def extend(self, records: Sequence[KeyframeRecord]) -> None:
        for r in records:
            self.rows[r.t_ns] = (r.T_W_B.p_A_B, r.T_W_B.R_A_B.as_quat())

    def trajectory(self) -> Trajectory:
        """The keyframes' poses in time order (the latest record of a stamp)."""
        t = sorted(self.rows)
        return Trajectory(
            t_ns=np.array(t, dtype=np.int64),
            p_W_B=np.array([self.rows[k][0] for k in t]).reshape(-1, 3),
            q_W_B_xyzw=np.array([self.rows[k][1] for k in t]).reshape(-1, 4),
            name="keyframes",
        )


def _event_json(e: OdometryEvent, t0: int) -> dict[str, object]:
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


def _status(state: OdometryState | None, t_s: float, rec: _Record) -> str:
    if state is None:
        return f"{t_s:6.2f} s  no estimate"
    return f"{t_s:6.2f} s  {state.status}  {state.tracked} tracked  reset {state.reset_counter}"


class _Pixels:
    """A frame's loader that hands the pixels the run already read to the first caller (the
    odometry), then lets them go and reads from the source again: the keyframe records keep a
    file's reference, not its pixels."""

    __slots__ = ("_image", "_load")

    def __init__(self, image: NDArray[np.uint8], load: Callable[[], NDArray[np.uint8]]) -> None:
        self._image: NDArray[np.uint8] | None = image
        self._load = load

    def __call__(self) -> NDArray[np.uint8]:
        image, self._image = self._image, None
        return image if image is not None else self._load()


def _push(vio: VisualOdometry, s: ImuSample | ImageFrame, rec: _Record) -> OdometryState | None:
    tic = time.perf_counter()
    state = vio.push(s)
    records = vio.keyframes()
    rec.estimator_s += time.perf_counter() - tic
    rec.published(records)
    return state


def _loop(
    vio: VisualOdometry,
    stream: Iterator[ImageFrame | ImuSample],
    n_frames: int,
    run_dir: Path,
    tracks: _Tracks,
    t0: int,
    progress: Progress | None,
    rec: _Record,
    primary: str,
) -> None:
    """Feed the stream to ``vio``, filling ``rec`` (kept as far as it got on an interrupt); the
    frames of ``primary`` are drawn and counted, those of its other cameras only pushed."""
    events = run_dir / "events.jsonl"
    events.touch()
    for s in stream:
        if isinstance(s, ImuSample) or s.camera != primary:
            # the IMU and the other cameras the odometry uses: a camera-rate state may come
            # from them too (a stereo pair completed by its right frame, a late partner given up)
            late = _push(vio, s, rec)
            if late is not None and late.status == "tracking":
                rec.keep(late)
            continue
        image = _image_of(s, rec, events, t0)
        if image is None:
            continue
        rec.first_frame_ns = s.t_ns if rec.first_frame_ns is None else rec.first_frame_ns
        frame = dataclasses.replace(s, load=_Pixels(image, s.load))
        state = _push(vio, frame, rec)
        rec.frames += 1
        if state is not None:
            rec.keep(state)
        _flush_events(vio, rec, events, t0)
        tracks.add(
            rec.frames - 1, image, vio.last_features, _status(state, ns_to_s(s.t_ns - t0), rec)
        )
        if rec.observer is not None:
            rec.observer.frame(s.t_ns, image, vio.last_features)
        if progress is not None:
            progress(rec.frames + rec.rejected, n_frames, f"{ns_to_s(s.t_ns - t0):.1f} s")


def _estimate(states: _States) -> tuple[Trajectory, FloatArray]:
    """The camera-rate estimate (time-ordered, one pose per stamp) and its pose covariances'
    upper triangles (N, 21; :func:`~quadnav.eval.vio_metrics.pose_covariances` expands them),
    taken from ``states`` (which lets them go): 232 bytes a frame, no copy when the states came
    in time order."""
    t_all, rows = states.take()
    if len(t_all) > 1 and not np.all(np.diff(t_all) > 0):
        # a repeated stamp (a stereo pair completed late): the later state, in time order
        last = len(t_all) - 1 - np.unique(t_all[::-1], return_index=True)[1]
        t_all, rows = t_all[last], rows[last]
    est = Trajectory(t_ns=t_all, p_W_B=rows[:, :3], q_W_B_xyzw=rows[:, 3:7], name="vio")
    return est, rows[:, 7:]


def _timing(vio: VisualOdometry, rec: _Record, wall_s: float) -> OdometryTiming:
    stages = vio.timing().stages
    frames = max(rec.frames, 1)
    return OdometryTiming(
        frames=rec.frames, estimator_s=rec.estimator_s,
        frames_per_s=rec.frames / rec.estimator_s if rec.estimator_s > 0 else 0.0,
        wall_s=wall_s, stage_ms_per_call=vio.timing().per_call_ms(),
        stage_ms_per_frame={name: 1e3 * s / frames for name, s, _ in stages},
        stage_calls={name: n for name, _, n in stages},
    )  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class _Scored:
    """The estimate and the ground truth matched to it (None without one), for the metrics
    and the plots; ``truth`` is the ground truth over the run's span; the covariances are
    upper triangles (N, 21; :func:`~quadnav.eval.vio_metrics.pose_covariances`)."""

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
    opt: OdometryRunOptions,
) -> _Scored:
    gt = dataset.groundtruth
    if gt is None:
        return _Scored(est=est, cov=cov)
    tr = gt.trajectory
    a, b = (int(k) for k in np.searchsorted(tr.t_ns, [t0, t1 + 1]))
    truth = tr if (a, b) == (0, len(tr)) else tr.select(slice(a, b))  # not a copy of it all
    if len(est) == 0 or len(truth) < 2:
        note = "no estimate to score" if len(est) == 0 else "no ground truth in the run's span"
        return _Scored(est=est, cov=cov, truth=truth if len(truth) else None, note=note)
    try:
        ref_m, est_m = associate(truth, est, t_max_diff_s=opt.t_max_diff_s, interpolate=True)
    except EvalError as exc:
        return _Scored(est=est, cov=cov, truth=truth, note=str(exc))
    # every estimate matched (the usual case): its covariances as they are, not a copy
    matched_cov = cov if len(est_m) == len(est) else cov[np.searchsorted(est.t_ns, est_m.t_ns)]
    return _Scored(
        est=est, cov=cov, matched_truth=ref_m, matched_est=est_m, matched_cov=matched_cov,
        truth=truth,
    )  # fmt: skip


def _counts(rec: _Record, vio: VisualOdometry, t0: int) -> RunCounts:
    kinds = [e.kind for e in vio.events]
    first = rec.states.first_t_ns
    after: Metric = (
        ns_to_s(first - (rec.first_frame_ns or t0))
        if first is not None
        else na("never initialised")
    )
    return RunCounts(
        frames=rec.frames + rec.rejected, failures=kinds.count("failure"),
        reinitializations=kinds.count("reinitialized"), rejected_images=rec.rejected,
        initialized_after_s=after, recoveries=kinds.count("recovered"),
    )  # fmt: skip


def run_odometry(
    dataset: VisualInertialDataset,
    rig: Rig,
    make_estimator: EstimatorFactory,
    out: Path,
    *,
    config_text: str = "",
    options: OdometryRunOptions | None = None,
    name: str = "",
    kind: str = "vio",
    progress: Progress | None = None,
    observer: OdometryObserver | None = None,
) -> OdometryRun:
    """Run the estimator ``make_estimator(rig)`` over ``dataset``'s IMU and the cameras it uses
    into a run folder ``<stamp>_<kind>_<name>`` under ``out`` (see the module), shown to
    ``observer`` as it goes; what it measured."""
    opt = options or OdometryRunOptions()
    start = time.perf_counter()
    t0, t1, frames = _span_frames(dataset, opt)
    vio = make_estimator(rig)
    run_dir = create_run_folder(out, f"{kind}_{name or dataset.name}")
    write_text(run_dir / "config.yaml", config_text)
    video = (
        VideoOut(run_dir / "tracks.mp4", rig.camera(opt.camera).rate_hz / opt.video_every)
        if opt.video
        else None
    )
    tracks = _Tracks(video=video, every=opt.video_every)
    rec = _Record(observer=observer)
    if observer is not None:
        observer.begin(rig, opt.camera, len(frames))
    completed = False
    try:
        _loop(
            vio,
            _stream(
                dataset,
                _cameras(vio, opt.camera),
                t0,
                t1,
                s_to_ns(opt.imu_lead_s),
                _blackout_ns(opt, t0),
            ),
            len(frames),
            run_dir,
            tracks,
            t0,
            progress,
            rec,
            opt.camera,
        )
        rec.published(vio.keyframes(final=True))
        # (the last keyframes' loops and events come with them)
        _flush_events(vio, rec, run_dir / "events.jsonl", t0)
        completed = True
    finally:
        if video is not None:
            video.close()
        est, cov = _estimate(rec.states)
        write_tum(run_dir / "estimate.tum", est)
        write_tum(run_dir / "keyframes.tum", rec.keyframes.trajectory())
        try:
            if completed and isinstance(vio, RefinedTrajectory):  # (not out of an error)
                rec.final = vio.final_trajectory()
                write_tum(run_dir / "estimate_final.tum", rec.final)
        finally:  # (a loop closer's outputs and its worker stopped, whatever happened)
            _loop_outputs(vio, rec, run_dir, opt, t0)
    run = _finish(dataset, vio, rec, run_dir, est, cov, (t0, t1), opt, time.perf_counter() - start)
    _write_calibration(vio, rig, dataset, run_dir)
    if observer is not None:
        observer.finish(run_dir)
    return run


def _write_calibration(
    vio: VisualOdometry, rig: Rig, dataset: VisualInertialDataset, run_dir: Path
) -> None:
    """``calibration.json`` of an odometry that refines its calibration online (see
    :mod:`quadnav.experiments.odometry_calibration`)."""
    from quadnav.experiments.odometry_calibration import (
        CAMCHAIN_ONLINE,
        calibrated_rig,
        calibration_report,
        truth_rig,
    )
    from quadnav.io.datasets.kalibr import write_camchain

    report = calibration_report(vio, rig, truth_rig(getattr(dataset, "root", None)))
    if report is not None and isinstance(vio, OnlineCalibration):
        write_json(run_dir / "calibration.json", report)
        write_camchain(run_dir / CAMCHAIN_ONLINE, calibrated_rig(rig, vio.calibration()))


def _loop_outputs(
    vio: VisualOdometry, rec: _Record, run_dir: Path, opt: OdometryRunOptions, t0: int
) -> None:
    """With loop closure: the keyframes as the final pose graph has them
    (``keyframes_loop.tum``), its counts (``loop.json``, with the time from a blackout's end to
    the first relocalization after it), the map saved if asked; the graph's worker stopped."""
    save_map = opt.save_map
    from quadnav.io.loop_map import save_loop_map
    from quadnav.loop import LoopClosure
    from quadnav.loop.closer import FINAL_WAIT_S

    if not isinstance(vio, LoopClosure):
        return
    saved: dict[str, object] = {}
    try:
        vio.graph.wait(timeout_s=FINAL_WAIT_S)
        write_tum(run_dir / "keyframes_loop.tum", vio.corrected_keyframes())
        if save_map is not None:
            the_map = vio.export_map()
            save_loop_map(save_map, the_map)
            saved = {"map_saved": str(save_map), "map_saved_keyframes": len(the_map.keyframes)}
    finally:
        vio.close()
    from quadnav.loop.settings import loop_settings

    settings = {"settings": loop_settings(vio.config)}
    blackout = _blackout_json(vio.stats.joins, opt, t0)
    write_json(run_dir / "loop.json", {**vio.stats.as_json(), **saved, **settings, **blackout})


def _blackout_json(
    joins: Sequence[Mapping[str, object]], opt: OdometryRunOptions, t0: int
) -> dict[str, object]:
    """``--blackout``'s window and how long after the images came back the run relocalized
    (None: it did not)."""
    window = _blackout_ns(opt, t0)
    if window is None:
        return {}
    after = [int(str(j["t_ns"])) - window[1] for j in joins if int(str(j["t_ns"])) >= window[1]]
    return {
        "blackout": {
            "start_s": ns_to_s(window[0] - t0), "end_s": ns_to_s(window[1] - t0),
            "relocalized_after_s": ns_to_s(min(after)) if after else None,
        }
    }  # fmt: skip


def _final_metrics(
    final: Trajectory | None,
    truth: Trajectory | None,
    opt: OdometryRunOptions,
    vio: VisualOdometry | None = None,
) -> dict[str, object] | None:
    """The final trajectory's APE after SE(3) and Sim(3) alignments (None: none, or no truth),
    with what the odometry's final smoothing did where it has one."""
    report = getattr(vio, "smoothing", None)
    smoothing: dict[str, object] = (
        {"smoothing": dataclasses.asdict(report)} if report is not None else {}
    )
    if final is None or truth is None or len(final) < 3:
        return smoothing or None
    try:
        ref_m, est_m = associate(truth, final, t_max_diff_s=opt.t_max_diff_s, interpolate=True)
    except EvalError:
        return smoothing or None
    return {
        "ape_se3": dataclasses.asdict(ape_summary(ref_m, est_m, "se3")),
        "ape_sim3": dataclasses.asdict(ape_summary(ref_m, est_m, "sim3")),
        "note": "every tracked frame through its reference keyframe's final pose (not causal)",
        **smoothing,
    }


def _finish(
    dataset: VisualInertialDataset,
    vio: VisualOdometry,
    rec: _Record,
    run_dir: Path,
    est: Trajectory,
    cov: FloatArray,
    span: tuple[int, int],
    opt: OdometryRunOptions,
    wall_s: float,
) -> OdometryRun:
    scored = _score(dataset, est, cov, span[0], span[1], opt)
    if scored.truth is not None:
        write_tum(run_dir / "groundtruth.tum", scored.truth)
    metrics = vio_metrics(
        scored.matched_truth, scored.matched_est if scored.matched_est is not None else est,
        _counts(rec, vio, span[0]), cov_pose=scored.matched_cov, drift_first_s=opt.drift_first_s,
        unscored=scored.note or "the dataset has no ground truth",
        levelled=getattr(vio, "levelled", True),  # (the SLAM's world is its first pose)
    )  # fmt: skip
    issues = dataset.issues.for_cameras([opt.camera])  # not those of a camera left unused
    counts = dict(sorted(vio.rejected.items()))
    said = ", ".join(f"{k} {v}" for k, v in counts.items())
    notes = [
        n for n in (scored.note, issues.summary() if issues else "",
                    f"input the odometry rejected or did not use: {said}" if said else "") if n
    ]  # fmt: skip
    run = OdometryRun(
        run_dir=run_dir, dataset=dataset.name, camera=opt.camera, metrics=metrics,
        timing=_timing(vio, rec, wall_s), events=vio.events, notes=tuple(notes),
        input_counts=counts, final=_final_metrics(rec.final, scored.truth, opt, vio),
    )  # fmt: skip
    write_json(run_dir / "timing.json", dataclasses.asdict(run.timing))
    from quadnav.experiments.odometry_report import (
        loop_evaluation,
        write_nees,
        write_odometry_outputs,
    )

    levelled = getattr(vio, "levelled", True)
    write_nees(run_dir, scored.matched_truth, scored.matched_est, scored.matched_cov, levelled)

    loop = loop_evaluation(vio, rec.keyframes.trajectory(), scored.truth)  # None without --loop
    write_json(run_dir / "metrics.json", run.as_json() | (loop.as_metrics() if loop else {}))
    write_odometry_outputs(run, scored.matched_truth, scored.matched_est, scored.truth, est, loop)
    return run
