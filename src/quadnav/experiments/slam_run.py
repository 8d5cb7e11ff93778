"""``quadnav slam``: the stereo SLAM (:class:`quadnav.slam.SlamOdometry`) over a dataset, through
the runner every visual estimator shares (:func:`~quadnav.experiments.odometry_run.run_odometry`:
the run folder, trajectory, metrics against the ground truth, report), and the map's keyframes
as they end (``keyframes_final.tum``: after loop closing). ``load_map`` starts it
on a map saved before (by ``save_map``), ``localization_only`` without adding to it."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from quadnav.errors import ConfigError
from quadnav.experiments.odometry_run import (
    OdometryRun,
    OdometryRunOptions,
    Progress,
    check_out_and_rig,
    resolve_dataset,
    run_odometry,
)
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.serial_frame import FrameSender
from quadnav.io.trajectory_io import write_tum
from quadnav.messages import ImageFrame, ImuSample
from quadnav.odometry import (
    FrameFeatures,
    KeyframeRecord,
    OdometryEvent,
    OdometryState,
    StageTiming,
    VisualOdometry,
)
from quadnav.viz.background import RecordingProcess
from quadnav.viz.odometry_capture import capture_if
from quadnav.viz.recording import require_rerun
from quadnav.viz.stream import RerunOptions

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from quadnav.io.datasets.types import VisualInertialDataset
    from quadnav.rig import Rig
    from quadnav.slam import SlamConfig, SlamOdometry
    from quadnav.slam.frame import StereoCamera
    from quadnav.slam.map import SlamMap
    from quadnav.slam.odometry import DepthSource
    from quadnav.vision.stereo import RectificationFix

__all__ = [
    "FINAL_INTRINSICS",
    "FINAL_KEYFRAMES",
    "SendingOdometry",
    "SlamRequest",
    "check_slam_request",
    "final_keyframes",
    "run_slam_source",
]

#: the run folder's file of the map's keyframes at the end of the run (:func:`final_keyframes`)
FINAL_KEYFRAMES = "keyframes_final.tum"
#: the run folder's file of the intrinsics the final bundle adjustment estimated
FINAL_INTRINSICS = "final_intrinsics.json"
#: its ``format`` (read back by ``--intrinsics``)
FINAL_INTRINSICS_FORMAT = "quadnav-final-intrinsics 1"


@dataclass(frozen=True, slots=True, kw_only=True)
class SlamRequest:
    """One ``quadnav slam`` run: the source, its span and outputs, the seed and rig of a
    built-in sequence, the runs' folder, the SLAM's features and ThDepth, its loop closing
    (``loop``) and final bundle adjustment (``final_ba``), the map saved at the end (``save_map``) or started on (``load_map``),
    ``localization_only``, a ``calibration`` replacing the dataset's, and ``intrinsics``: an
    earlier run's ``final_intrinsics.json`` whose estimated rectified camera is tracked in."""

    source: str
    options: OdometryRunOptions = field(default_factory=OdometryRunOptions)
    seed: int = 0
    rig: str = "euroc"
    out: Path = Path("runs")
    n_features: int = 1200
    th_depth_baselines: float = 40.0
    loop: bool = True
    final_ba: bool = True
    save_map: Path | None = None
    load_map: Path | None = None
    localization_only: bool = False
    #: a Kalibr camchain or EuRoC folder whose calibration replaces the dataset's own
    calibration: Path | None = None
    #: an earlier run's final_intrinsics.json: the rectified camera its final adjustment found
    intrinsics: Path | None = None
    #: write the run's rerun recording (``recording.rrd``, with ``viz.npz``) into its folder
    rerun: RerunOptions | None = None


class SendingOdometry:
    """An odometry whose states' positions (the body's, in its world: the run's trajectory)
    go out as thesis 002's serial frames through ``sender`` as they are estimated (at the
    sender's rate in the data's time, 10 Hz in the thesis); otherwise the odometry itself."""

    def __init__(self, inner: VisualOdometry, sender: FrameSender) -> None:
        self.inner, self.sender = inner, sender

    @property
    def cameras(self) -> tuple[str, ...]:
        return self.inner.cameras

    def push(self, sample: ImuSample | ImageFrame) -> OdometryState | None:
        state = self.inner.push(sample)
        if state is not None:
            self.sender.offer(state.t_ns, state.T_W_B.p_A_B)
        return state

    def keyframes(self, *, final: bool = False) -> Sequence[KeyframeRecord]:
        return self.inner.keyframes(final=final)

    def newest_keyframe(self) -> KeyframeRecord | None:
        return self.inner.newest_keyframe()

    @property
    def events(self) -> tuple[OdometryEvent, ...]:
        return self.inner.events

    @property
    def last_features(self) -> FrameFeatures | None:
        return self.inner.last_features

    @property
    def rejected(self) -> Mapping[str, int]:
        return self.inner.rejected

    def timing(self) -> StageTiming:
        return self.inner.timing()


def check_slam_request(request: SlamRequest) -> None:
    """Refuse a bad rig, setting or ``--out`` before any dataset is read or made."""
    from quadnav.errors import QuadnavError

    if request.rerun:
        require_rerun("--rerun")
    rig = check_out_and_rig(request.out, request.rig)
    if not rig.stereo and rig.depth is None:
        raise ConfigError(
            f"--rig {request.rig}: one camera and no depth; the SLAM needs a stereo rig (euroc, "
            "zed) or an RGB-D one (rgbd)"
        )
    try:
        _config(request)
    except QuadnavError as exc:
        raise ConfigError(f"--features/--th-depth: {exc}") from None
    if request.localization_only and request.load_map is None:
        raise ConfigError("--localization-only: give the map to localize in (--load-map DIR)")
    if request.localization_only and request.save_map is not None:
        raise ConfigError("--save-map with --localization-only: the map does not change")
    if request.save_map is not None and request.save_map == request.load_map:
        raise ConfigError(f"--save-map {request.save_map}: the map loaded; save to another folder")


def _config(request: SlamRequest) -> SlamConfig:
    from quadnav.slam import SlamConfig
    from quadnav.slam.config import LoopClosingConfig
    from quadnav.vision.orb import OrbConfig

    return SlamConfig(orb=OrbConfig(n_features=request.n_features),
                      th_depth_baselines=request.th_depth_baselines,
                      loop_closing=LoopClosingConfig(enabled=request.loop),
                      final_ba=request.final_ba)  # fmt: skip


def run_slam_source(
    request: SlamRequest,
    progress: Progress | None = None,
    *,
    serial: Callable[[bytes], object] | None = None,
) -> OdometryRun:
    """The dataset (made once if a built-in sequence), the SLAM on its rig, into a run folder;
    the map saved at the end if asked; with ``serial`` (a port's write), each position also
    sent as thesis 002's frame at 10 Hz as it is tracked (:class:`SendingOdometry`)."""
    import dataclasses

    import yaml

    opt = request.options
    loaded = None
    # (a missing or malformed file fails before anything is made, as a map does)
    found = None if request.intrinsics is None else read_final_intrinsics(request.intrinsics)
    if request.load_map is not None:  # (a missing or corrupt map fails before anything is made)
        from quadnav.io.slam_map import load_slam_map

        loaded = load_slam_map(request.load_map)
        own = request.load_map / FINAL_INTRINSICS  # (the calibration the map was adjusted in)
        if found is None and own.is_file():
            found = read_final_intrinsics(own, option="--load-map")
    dataset = resolve_dataset(
        request.source, seed=request.seed, rig=request.rig, duration_s=opt.duration_s,
        start_s=opt.start_s, cache_root=request.out, calibration=request.calibration,
        progress=progress,
    )  # fmt: skip
    if not dataset.rig.stereo and not dataset.depth:
        raise ConfigError(
            f"{request.source}: one camera and no depth images; the SLAM needs stereo or RGB-D"
        )
    cfg = _config(request)
    settings = yaml.safe_dump(dataclasses.asdict(cfg), sort_keys=False)
    text = f"# dataset: {dataset.root}\n# rig: {dataset.rig.name}\n{settings}"
    source = request.source
    name = Path(source).name if Path(source).exists() else f"{source}_s{request.seed}"
    made: list[SlamOdometry] = []

    depth = _depth_source(dataset) if not dataset.rig.stereo else None

    def make(rig: Rig) -> VisualOdometry:
        made.append(_slam(request, rig, cfg, loaded, depth, found))
        return made[-1] if serial is None else SendingOdometry(made[-1], FrameSender(serial))

    recorder = RecordingProcess(request.rerun) if request.rerun else None  # imports rerun meanwhile
    run = run_odometry(
        dataset, dataset.rig, make, request.out, config_text=text,
        options=replace(opt, video=False, save_map=None), name=name, kind="slam",
        progress=progress, observer=capture_if(request.rerun is not None),
    )  # fmt: skip
    if made:
        write_tum(run.run_dir / FINAL_KEYFRAMES, final_keyframes(made[0]))
        _write_final_intrinsics(made[0], run.run_dir / FINAL_INTRINSICS)
    if recorder is not None:  # from the folder's files and viz.npz, as quadnav view would
        recorder.record(run.run_dir, "odometry")
    if request.save_map is not None and made:
        from quadnav.io.slam_map import save_slam_map

        save_slam_map(request.save_map, made[0].slam_map, made[0].map_camera)
        # (with the calibration the map was adjusted in: a run that loads it tracks in it)
        _write_final_intrinsics(made[0], request.save_map / FINAL_INTRINSICS)
    notes = [] if found is None else [few_views_note(found)]
    if found is not None and found.source.startswith("--load-map"):
        notes.append(f"{found.source}: tracked in the calibration the map was adjusted in")
    return replace(run, notes=(*run.notes, *(n for n in notes if n)))


#: a calibration found from fewer keyframes than this is poorly determined (MH_01's 40 s down
#: the hall: 3-8 keyframes, one seed's fy 2.5 % long against a truth 0.76 % short)
FEW_VIEWS = 10


def few_views_note(found: FoundIntrinsics) -> str | None:
    """A note when ``found`` came from fewer than :data:`FEW_VIEWS` keyframes; None otherwise,
    or when its file does not say."""
    if found.keyframes is None or found.keyframes >= FEW_VIEWS:
        return None
    return (
        f"{found.source}: its calibration was found from {found.keyframes} keyframes; "
        f"under {FEW_VIEWS} determine it poorly, and tracking in it may be worse"
    )


def _write_final_intrinsics(slam: SlamOdometry, path: Path) -> None:
    """The rectified left camera's intrinsics as stated and as the final adjustment estimated
    them (nothing written when it did not)."""
    import json

    import numpy as np

    from quadnav.io.run_folder import write_text

    found = slam.final_intrinsics
    if found is None:
        return
    keys = ("fx", "fy", "cx", "cy")

    def camera(c: StereoCamera) -> dict[str, float]:
        return {"fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy, "baseline_m": c.baseline_m}

    stated = camera(slam.rectified)
    estimated = dict(zip(keys, found[:4], strict=True))
    extra: dict[str, object] = {}
    cal = slam.final_calibration
    if cal is not None:
        names = ("k1", "k2", "p1", "p2")
        extra["keyframes"] = cal.keyframes
        extra["right_estimated"] = dict(zip(keys, cal.right, strict=True))
        extra["distortion"] = {side: dict(zip(names, d, strict=True))
                               for side, d in zip(("left", "right"), cal.distortion, strict=True)}  # fmt: skip
        extra["right_from_left"] = {
            "rotation_deg": [float(v) for v in np.degrees(cal.T_L_R.R_A_B.as_rotvec())],
            "translation_m": [float(v) for v in cal.T_L_R.p_A_B],
        }
    text = json.dumps({
        "what": "the rectified left camera (px): as the calibration states it (stated), as the "
        "tracking used it (tracked_with: the stated one, or one given by --intrinsics) and as "
        "the final bundle adjustment estimated it with the map (estimated; give this file to "
        "the next run's --intrinsics to track in it); the adjustment also found the right "
        "camera's (right_estimated), the distortion left in each rectified image (OpenCV's k1, "
        "k2, p1, p2; a calibration's error undistorts them wrongly) and the right camera's "
        "pose from the left one (rotation vector, translation; the baseline's length held), "
        "which the next run folds into its rectification, from this many keyframes (under ten "
        "determine it poorly); rectification: whether this run's "
        "was the stated calibration's or corrected by an earlier run's file",
        "format": FINAL_INTRINSICS_FORMAT,
        "rectification": "stated" if slam.fix is None else "corrected",
        "stated": stated, "tracked_with": camera(slam.camera), "estimated": estimated,
        "difference": {k: estimated[k] - stated[k] for k in keys}, **extra,
    }, indent=2)  # fmt: skip
    write_text(path, text + "\n")


class FoundIntrinsics(NamedTuple):
    """A ``final_intrinsics.json``: the rectified camera as stated, and as estimated; with the
    rest of what was found (the right camera, the distortion, the rig) when the file has it, as
    the rectification's fix (None: an older file, the left pinhole only)."""

    stated: tuple[float, float, float, float, float]  # (fx, fy, cx, cy, baseline_m)
    estimated: tuple[float, float, float, float]  # (fx, fy, cx, cy)
    fix: RectificationFix | None = None
    keyframes: int | None = None  # (the views it was found from; None: not said)
    source: str = "--intrinsics"  # (where it came from: the option and file, for messages)


def read_final_intrinsics(path: Path, *, option: str = "--intrinsics") -> FoundIntrinsics:
    """An earlier run's ``final_intrinsics.json`` (:data:`FINAL_INTRINSICS`); a missing or
    malformed file is a one-line :class:`~quadnav.errors.ConfigError` naming ``option``
    (``--load-map`` for the one a saved map's folder holds)."""
    import json
    import math

    if not path.is_file():
        raise ConfigError(f"{option} {path}: no such file (a SLAM run's {FINAL_INTRINSICS})")
    try:
        data = json.loads(path.read_text())
        stated = tuple(float(data["stated"][k]) for k in ("fx", "fy", "cx", "cy", "baseline_m"))
        est = tuple(float(data["estimated"][k]) for k in ("fx", "fy", "cx", "cy"))
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, OverflowError) as exc:
        raise ConfigError(
            f"{option} {path}: not a SLAM run's {FINAL_INTRINSICS} ({type(exc).__name__}: {exc})"
        ) from None
    if data.get("rectification", "stated") != "stated":
        raise ConfigError(
            f"{option} {path}: made by a run that tracked in an earlier run's calibration "
            "(its values are relative to that one); give the earlier run's file"
        )
    if not all(math.isfinite(v) for v in (*stated, *est)):
        raise ConfigError(f"{option} {path}: a value is not finite")
    if min(stated[0], stated[1], stated[4], est[0], est[1]) <= 0:
        raise ConfigError(f"{option} {path}: a focal length or the baseline is not positive")
    try:
        fix = _fix_of(data, est) if "distortion" in data else None
    except (ValueError, KeyError, TypeError, OverflowError) as exc:
        raise ConfigError(
            f"{option} {path}: the calibration found is unreadable ({type(exc).__name__}: {exc})"
        ) from None
    views = data.get("keyframes")
    ok = isinstance(views, int | float) and not isinstance(views, bool)
    views = int(views) if ok and math.isfinite(views) and 0 <= views < 10**9 else None
    return FoundIntrinsics(
        stated=stated,  # type: ignore[arg-type]
        estimated=est,  # type: ignore[arg-type]
        fix=fix, keyframes=views, source=f"{option} {path}",
    )  # fmt: skip


def _fix_of(data: dict[str, Any], est: tuple[float, ...]) -> RectificationFix:
    """The rectification's fix a ``final_intrinsics.json`` gives (its right camera, distortion
    and rig); a value missing, of the wrong kind or not finite raises (the caller names the
    option)."""
    import numpy as np

    from quadnav.errors import VisionError
    from quadnav.vision.stereo import RectificationFix

    right = [float(data["right_estimated"][k]) for k in ("fx", "fy", "cx", "cy")]
    dist = [
        [float(data["distortion"][side][k]) for k in ("k1", "k2", "p1", "p2")]
        for side in ("left", "right")
    ]
    turn = np.radians([float(v) for v in data["right_from_left"]["rotation_deg"]])
    if not np.all(np.isfinite([*right, *dist[0], *dist[1]])):
        raise ValueError("the right camera or a distortion is not finite")
    if turn.shape == (3,) and np.degrees(np.linalg.norm(turn)) > 5.0:
        raise ValueError("the rig turned over 5 deg: not a small fix")
    if np.abs(np.array(dist)).max() > 1.0:
        raise ValueError("a distortion over 1: not a small fix")
    for name, a, b, scale in (
        ("fx", right[0], est[0], est[0]),
        ("cx", right[2], est[2], 2 * est[2]),
    ):
        if not abs(a - b) <= 0.05 * abs(scale):
            raise ValueError(f"the right camera's {name} is more than 5 % off the left one's")
    try:
        return RectificationFix.of(est, right, dist[0], dist[1], turn)
    except VisionError as exc:
        raise ValueError(str(exc)) from None


def _check_found_for(found: FoundIntrinsics, rectified: StereoCamera) -> str | None:
    """Why ``found`` was not estimated for this rectified camera (None when it was: the
    stated camera the same within 0.1 %)."""
    from quadnav.slam.frame import StereoCamera

    fx, fy, cx, cy, baseline_m = found.stated
    there = StereoCamera(fx=fx, fy=fy, cx=cx, cy=cy, baseline_m=baseline_m)
    why = rectified.mismatch(there, 1e-3)
    return (
        None
        if why is None
        else (f"estimated for another rectified camera ({why}); the calibration differs")
    )


def final_keyframes(slam: SlamOdometry) -> Trajectory:
    """The map's keyframes as it has them at the end (after local and global bundle adjustment
    and loop closing), culled ones left out: the body's pose in the run's world, as the
    states and ``keyframes.tum`` (which has each keyframe when it left the local window); in
    time order (a map loaded by ``--load-map`` brings its own keyframes and times)."""
    import numpy as np

    by_t = {kf.frame.t_ns: kf for kf in slam.slam_map.keyframes if not kf.bad}
    kfs = [by_t[t] for t in sorted(by_t)]
    poses = [slam.T_O_S @ kf.T_C_W.inverse() @ slam.T_B_C.inverse() for kf in kfs]
    return Trajectory(
        t_ns=np.array([kf.frame.t_ns for kf in kfs], dtype=np.int64),
        p_W_B=np.array([T.p_A_B for T in poses]).reshape(-1, 3),
        q_W_B_xyzw=np.array([T.R_A_B.as_quat() for T in poses]).reshape(-1, 4),
        name="keyframes_final",
    )


def _depth_source(dataset: VisualInertialDataset) -> DepthSource:
    """The dataset's depth image at a time (None where it has none)."""
    by_t = {d.t_ns: d for d in dataset.depth}

    def depth(t_ns: int) -> NDArray[np.floating] | None:
        d = by_t.get(t_ns)
        return None if d is None else d.depth_m()

    return depth


def _slam(
    request: SlamRequest, rig: Rig, cfg: SlamConfig, loaded: tuple[SlamMap, StereoCamera] | None,
    depth: DepthSource | None, found: FoundIntrinsics | None = None,
) -> SlamOdometry:  # fmt: skip
    from quadnav.errors import SlamError
    from quadnav.slam import SlamOdometry

    given = None if found is None else found.estimated
    fix = None if found is None else found.fix
    if found is not None:
        try:
            odo = SlamOdometry(rig, cfg, depth=depth, intrinsics=given, fix=fix)
        except SlamError as exc:
            raise SlamError(f"{found.source}: {exc}") from None
        if (why := _check_found_for(found, odo.rectified)) is not None:
            raise SlamError(f"{found.source}: {why}")
        if loaded is None:
            return odo
    elif loaded is None:
        return SlamOdometry(rig, cfg, depth=depth)
    try:
        return SlamOdometry(rig, cfg, slam_map=loaded[0], map_camera=loaded[1],
                            mapping=not request.localization_only, depth=depth,
                            intrinsics=given, fix=fix)  # fmt: skip
    except SlamError as exc:
        raise SlamError(f"--load-map {request.load_map}: {exc}") from None
