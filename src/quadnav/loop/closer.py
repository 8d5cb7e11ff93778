"""Loop closure for any odometry (VINS-Mono's ``pose_graph`` node), behind the same interface.

:class:`LoopClosure` wraps a :class:`~quadnav.odometry.VisualOdometry` and is one itself: a run, a
closed loop or a fusion drives it as it would drive the odometry. Each keyframe the odometry
finishes with (leaving its window, as VINS-Mono's marginalised keyframes reach its pose graph):

1. joins the pose graph (:class:`~quadnav.posegraph.BackgroundPoseGraph`, 4-DoF by default) with
   its odometry pose;
2. queries the place database with its descriptors (:class:`~quadnav.place.LoopDetector`:
   DBoW2's normalised score, islands, temporal consistency) and is added to it;
3. when a place is recognised, the two keyframes are verified in geometry
   (:func:`~quadnav.place.verification.verify_place`: descriptor matches, fundamental matrix,
   PnP against the landmarks of the old keyframe and its neighbours, the yaw and distance
   check); a verified loop
   becomes a loop edge and the graph optimises in the background.

The output is the odometry's state in the map (``T_M_O @ T_O_B``, the latest correction), with
the reset counter raised when a correction jumps. Every recognised place, verified or not, is
an event (``loop`` or ``loop_rejected``, with the stage it failed at) and counted in
:attr:`LoopClosure.stats`.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import LoopError, QuadnavError
from quadnav.geometry.rotations import Pose
from quadnav.geometry.trajectory import Trajectory
from quadnav.loop.map import MAP_FRAME, LoopMap, MapCamera, MapKeyframe
from quadnav.loop.relocalize import (
    RelocCandidate,
    Segment,
    Segments,
    continuing_frame,
    four_dof,
    transform_gap,
)
from quadnav.messages import ImageFrame, ImuSample
from quadnav.odometry import (
    CameraCalibration,
    EventKind,
    FrameFeatures,
    KeyframeRecord,
    LoopConstraint,
    LoopRefinedTrajectory,
    OdometryEvent,
    OdometryState,
    OnlineCalibration,
    StageTiming,
    VisualOdometry,
)
from quadnav.place.detector import LoopDetector, LoopDetectorConfig, islands
from quadnav.place.features import describe_image
from quadnav.place.verification import LoopMatch, Verification, VerificationConfig, verify_place
from quadnav.place.vocabulary import BowVector
from quadnav.posegraph.background import BackgroundPoseGraph, Executor
from quadnav.posegraph.types import LoopEdge, PoseGraphConfig
from quadnav.rig import CameraSpec
from quadnav.units import NS_PER_S, s_to_ns

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: The longest the last keyframes wait for the pose graph's solve (s): a run never hangs on it.
FINAL_WAIT_S = 60.0

__all__ = [
    "LOOP_GRAPH",
    "LoopClosure",
    "LoopConfig",
    "LoopStats",
    "PlaceEvent",
    "local_map",
    "loop_constraint",
]

#: The pose graph of loop closure. A loop edge carries the covariance its PnP fixes (a few
#: centimetres and a degree on 25-50 inliers); the odometry between keyframes is held to 5 mm
#: and 0.1 degrees an edge (the VIO drifts 0.3-1 % of the distance, keyframes 0.1-0.2 m apart):
#: looser, a loop measured worse than the odometry's own drift pulls the keyframes off.
LOOP_GRAPH = PoseGraphConfig(
    sequential_sigma_m=0.005, sequential_sigma_yaw_rad=0.002,
    loop_sigma_m=0.02, loop_sigma_yaw_rad=0.01,
)  # fmt: skip
#: Place recognition before verification: DLoopDetector's own normalised score (0.3), with
#: five consistent queries. The detector's stricter default (0.7) is for recognition alone; here
#: every candidate is verified in geometry, and on two laps of the room (realistic, seed 0) 0.7
#: found no revisit of the first lap from the second (0.45 m higher, turned 25 degrees).
LOOP_DETECTOR = LoopDetectorConfig(min_normalised_score=0.3, temporal_consistency=5)


@dataclass(frozen=True, slots=True, kw_only=True)
class LoopConfig:
    """Loop closure's settings: place recognition (``detector``), verification, the fewest
    keyframes between two loops closed (``min_keyframes_between``), the corners of its own a
    keyframe's image adds to its tracked ones for recognition and verification
    (``extra_corners``: VINS-Mono adds 500; 0: none), the keyframes either side of a recognised
    one whose landmarks it is verified against (``local_map_keyframes``), the most drift a loop
    may say the odometry made since the old keyframe (``max_drift_m`` plus ``max_drift_fraction``
    of the path flown in between: a place that only looks like the old one, in a world of
    repeated textures, passes the geometric checks with a correction of metres), the pose graph
    (4-DoF by default, loop edges held to ``graph``'s loop sigmas), where it solves
    (``executor``: a worker process by default, GTSAM holding the GIL while it solves), and
    relocalization (:mod:`quadnav.loop.relocalize`: the gap in images that starts a new segment
    ``image_gap_s``, and the agreement and jump limits of a relocalization). A loop edge's
    covariance is its PnP's plus ``loop_floor_m`` and ``loop_floor_yaw_rad`` squared: what the
    PnP leaves out, the error of the old keyframe's landmarks (on stereo laps of the room,
    realistic sensors, the loops' measurements were 1.6 cm and 0.39 degrees off, median, where
    their PnP claimed 0.5 cm and 0.08: the graph bent the first lap to them, and the output,
    corrected by them, came out worse than the odometry's).

    The odometry's own covariance is used twice (``use_odometry_covariance``): a keyframe's
    sequential edges are loosened where its position variance grew faster than ``graph``'s
    sequential sigma allows (a fast drift, as corridor1's height, that loops can then correct;
    see :class:`~quadnav.posegraph.PoseGraphConfig`), and a loop within one segment is refused
    as drift when the move it implies has a chi-square, against both keyframes' position
    covariances and the loop's own, above ``max_drift_chi2`` (16.27: 99.9 % for three
    degrees of freedom; 0: no such check). On the real motions (stereo, realistic sensors) true
    loops came at 0.6-5 and the false ones, two metres off, at about 2,000.

    The sequential edges' variance is the odometry's steps' (:class:`KeyframeStep`), which
    treats each step's error as its own. A monocular VIO's errors are not: its scale wanders
    slowly, so over a lap it drifts more than its steps add up to. With
    ``learn_step_scale``, the loops say by how much: each accepted loop within a segment
    compares the move it measures, beyond its own variance, with the steps' variance between
    its keyframes. Each loop's ratio is held to at most ``max_step_scale`` (one loop measured
    worse than it says would otherwise scale every step: one in a simulated flight said 263x).
    The ratios are averaged over the loops so far with ``step_scale_prior_loops`` loops' worth
    of agreement (1), and the steps are scaled by that from the next solve on, never below 1
    (never tighter than the odometry says). On the hall's mono laps (realistic sensors) the
    loops found 1.8-7.4x; on stereo runs about 1."""

    detector: LoopDetectorConfig = field(default_factory=lambda: LOOP_DETECTOR)
    verification: VerificationConfig = field(default_factory=VerificationConfig)
    graph: PoseGraphConfig = field(default_factory=lambda: LOOP_GRAPH)
    min_keyframes_between: int = 5
    extra_corners: int = 400
    local_map_keyframes: int = 5
    max_drift_fraction: float = 0.1
    max_drift_m: float = 0.3
    executor: Executor = "process"
    image_gap_s: float = 0.5
    relocalize_window_s: float = 2.0
    relocalize_agree_m: float = 0.3
    relocalize_agree_rad: float = 0.1
    relocalize_max_jump_m: float = 1.5
    relocalize_max_jump_rad: float = 0.35
    loop_floor_m: float = 0.015
    loop_floor_yaw_rad: float = 0.007
    use_odometry_covariance: bool = True
    max_drift_chi2: float = 16.27
    learn_step_scale: bool = True
    step_scale_prior_loops: float = 3.0
    max_step_scale: float = 10.0

    def __post_init__(self) -> None:
        if not 0 <= self.min_keyframes_between <= 100_000:
            raise LoopError(
                f"LoopConfig.min_keyframes_between must be 0-100000, got {self.min_keyframes_between}"
            )
        if not 0 <= self.local_map_keyframes <= 100:
            raise LoopError(
                f"LoopConfig.local_map_keyframes must be 0-100, got {self.local_map_keyframes}"
            )
        if not (0.0 <= self.max_drift_fraction <= 10.0 and 0.0 <= self.max_drift_m <= 1e4):
            raise LoopError(
                "LoopConfig.max_drift_fraction must be 0-10 and max_drift_m 0-10000, got "
                f"{self.max_drift_fraction} and {self.max_drift_m}"
            )
        if not 0 <= self.extra_corners <= 5000:
            raise LoopError(f"LoopConfig.extra_corners must be 0-5000, got {self.extra_corners}")
        for name in ("image_gap_s", "relocalize_window_s", "relocalize_agree_m",
                     "relocalize_agree_rad", "relocalize_max_jump_m", "relocalize_max_jump_rad",
                     "loop_floor_m", "loop_floor_yaw_rad", "max_drift_chi2",
                     "step_scale_prior_loops"):  # fmt: skip
            v = getattr(self, name)
            least = 0.0 if name.startswith(("loop_floor", "max_drift", "step_")) else 1e-9
            if not (math.isfinite(v) and least <= v <= 1e4):
                raise LoopError(f"LoopConfig.{name} must be in [{least:g}, 10000], got {v}")
        if not (math.isfinite(self.max_step_scale) and 1.0 <= self.max_step_scale <= 1e6):
            raise LoopError(f"LoopConfig.max_step_scale must be 1-1e6, got {self.max_step_scale}")
        if self.executor not in ("process", "thread", "inline"):
            raise LoopError(
                f"LoopConfig.executor must be process, thread or inline, got {self.executor!r}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class PlaceEvent:
    """One recognised place: the keyframes (``old``, ``new``: indices and times), what each
    verification step kept, the ``stage`` it stopped at (``accepted``, a verification stage, or
    ``drift``), and for an accepted loop the measured pose of new in old, ``T_old_new``
    (x, y, z, qx, qy, qz, qw), and its 4-DoF sigmas (m, m, m, rad)."""

    old: int
    new: int
    t_old_ns: int
    t_new_ns: int
    stage: str
    n_matches: int
    n_fundamental: int
    n_pnp: int
    T_old_new: tuple[float, ...] | None = None
    sigma_4dof: tuple[float, ...] | None = None

    def as_json(self) -> dict[str, object]:
        return {
            "old": self.old, "new": self.new, "t_old_ns": self.t_old_ns, "t_new_ns": self.t_new_ns,
            "stage": self.stage, "matches": self.n_matches, "fundamental_inliers": self.n_fundamental,
            "pnp_inliers": self.n_pnp,
            "T_old_new_xyz_qxyzw": None if self.T_old_new is None else list(self.T_old_new),
            "sigma_4dof": None if self.sigma_4dof is None else list(self.sigma_4dof),
        }  # fmt: skip


@dataclass(slots=True)
class LoopStats:
    """Keyframes seen, places recognised, loops verified and accepted, and the rejections by
    verification stage; each recognised place as a :class:`PlaceEvent`."""

    keyframes: int = 0
    undescribed: int = 0
    unreadable: int = 0
    recognised: int = 0
    accepted: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    places: list[PlaceEvent] = field(default_factory=list)
    segments: int = 0
    map_keyframes: int = 0
    #: each segment joined to the map: time, segment, how (``relocalized``: two agreeing
    #: matches of the newest keyframe; ``loop``: a loop of a finished one), the map keyframe,
    #: and the jump of the output (m, deg)
    joins: list[dict[str, object]] = field(default_factory=list)
    relocalize_rejected: Counter[str] = field(default_factory=Counter)
    optimizations: int = 0
    failures: int = 0
    last_error: str = ""
    #: the scale the loops found for the odometry's step variances (1: as it says; see
    #: :class:`LoopConfig`'s ``learn_step_scale``) and how many loops measured it
    step_scale: float = 1.0
    step_scale_loops: int = 0
    #: loops the pose graph took but a final smoothing cannot (a degenerate covariance)
    unsmoothable: int = 0

    @property
    def loops(self) -> list[tuple[int, int]]:
        """The accepted loops' keyframes (old, new)."""
        return [(e.old, e.new) for e in self.places if e.stage == "accepted"]

    def as_json(self) -> dict[str, object]:
        return {
            "keyframes": self.keyframes, "undescribed": self.undescribed,
            "unreadable_images": self.unreadable,
            "recognised": self.recognised, "accepted": self.accepted,
            "rejected_by_stage": dict(self.rejected), "loops": [list(x) for x in self.loops],
            "places": [e.as_json() for e in self.places],
            "segments": self.segments, "map_keyframes": self.map_keyframes,
            "joins": self.joins, "relocalize_rejected": dict(self.relocalize_rejected),
            "graph_optimizations": self.optimizations, "graph_failures": self.failures,
            "graph_last_error": self.last_error, "step_scale": self.step_scale,
            "step_scale_loops": self.step_scale_loops, "unsmoothable_loops": self.unsmoothable,
        }  # fmt: skip


def loop_constraint(
    old: int, new: int, T_old_new: Pose, cov_4dof: FloatArray,
    matches: tuple[IntArray, FloatArray] | None = None,
) -> LoopConstraint:  # fmt: skip
    """A verified loop as a 6-DoF constraint (:class:`~quadnav.odometry.LoopConstraint`): the
    position's covariance (in the old keyframe's body frame) turned into the new one's, and
    the yaw's variance for all three turns (PnP fixes roll and pitch as well as yaw).
    ``matches``: the PnP's inliers, the old side's landmark ids and the new keyframe's
    normalised coordinates of them."""
    c = np.asarray(cov_4dof, dtype=np.float64)
    R = T_old_new.R_A_B.as_matrix()
    cov = np.zeros((6, 6))
    cov[:3, :3] = np.eye(3) * c[3, 3]
    cov[3:, 3:] = R.T @ c[:3, :3] @ R
    ids, xy = matches if matches is not None else (np.zeros(0, np.int64), np.zeros((0, 2)))
    return LoopConstraint(old=old, new=new, T_old_new=T_old_new, cov=cov, landmark_ids=ids, xy=xy)


def local_map(old: KeyframeRecord, near: Sequence[KeyframeRecord], T_B_C: Pose) -> KeyframeRecord:
    """Keyframe ``old`` with the landmarks its neighbours ``near`` saw (those of its odometry
    frame, described, in front of its camera): each landmark once, described as the keyframe
    nearest in time saw it, at its position there, and at its projection into ``old``'s camera
    (a verification against a local map, as ORB-SLAM's, not one keyframe's few points)."""
    T_C_W = (old.T_W_B @ (old.T_B_C or T_B_C)).inverse()
    seen: dict[int, tuple[int, NDArray[np.uint8], FloatArray]] = {}
    for rec in sorted(near, key=lambda r: abs(r.t_ns - old.t_ns), reverse=True):
        if rec.reset_counter != old.reset_counter or rec.descriptors is None:
            continue
        ok = np.ones(len(rec.ids), bool) if rec.described is None else rec.described
        row = {int(i): k for k, i in enumerate(rec.ids.tolist())}
        for j, X in zip(rec.landmark_ids.tolist(), rec.landmarks_W, strict=True):
            k = row.get(int(j))
            if k is not None and ok[k]:
                seen[int(j)] = (k, rec.descriptors[k], X)  # the nearest in time writes last
    if not seen:
        return old
    ids = np.array(list(seen), np.int64)
    X = np.array([v[2] for v in seen.values()], np.float64)
    desc = np.array([v[1] for v in seen.values()], np.uint8)
    c = T_C_W @ X
    front = c[:, 2] > 0.1
    ids, X, desc, c = ids[front], X[front], desc[front], c[front]
    xy = c[:, :2] / c[:, 2:3]
    return replace(
        old, ids=ids, uv_px=np.zeros((len(ids), 2)), xy=xy, descriptors=desc,
        described=np.ones(len(ids), bool), landmark_ids=ids, landmarks_W=X,
    )  # fmt: skip


class LoopClosure:
    """An odometry with loop closure and relocalization (see the module and
    :mod:`quadnav.loop.relocalize`). ``camera``: the rig's camera the keyframes are taken with
    (its lens undistorts the extra corners, its focal length turns the verification's pixel
    thresholds into normalised ones, its extrinsic stands where a keyframe carries none).
    ``loop_map``: a map saved by an earlier run (:meth:`export_map`), held fixed; the run
    reports in its frame once its first place is recognised."""

    def __init__(
        self, odometry: VisualOdometry, camera: CameraSpec, *, config: LoopConfig | None = None,
        loop_map: LoopMap | None = None,
    ) -> None:  # fmt: skip
        self.config = config or LoopConfig()
        self.odometry = odometry
        self._camera = camera
        self._focal_px = float(camera.camera.K[0, 0])
        self._T_B_C = camera.T_B_C
        self.detector = LoopDetector(config=self.config.detector)
        self.graph = BackgroundPoseGraph(self.config.graph, executor=self.config.executor)
        self.stats = LoopStats()
        self._records: dict[int, KeyframeRecord] = {}  # database entry -> keyframe (graph index)
        self._entry_of: dict[int, int] = {}  # graph index -> database entry
        self._by_index: dict[int, KeyframeRecord] = {}  # graph index -> keyframe
        self._segment_of: dict[int, int] = {}  # graph index -> segment (MAP_FRAME: the map's)
        self._raw: dict[int, Pose] = {}  # graph index -> its odometry pose
        self._out: list[KeyframeRecord] = []
        self._events: list[OdometryEvent] = []
        self._odometry_events = 0  # how many of the odometry's events are in ``_events``
        self._last_loop = -(10**9)
        self._t_of: dict[int, int] = {}  # graph index -> its time
        self._step_of: dict[int, float | None] = {}  # graph index -> its variance growth
        self._cum: dict[int, float] = {}  # this run's keyframes: step variances summed in a segment
        self._scale_sum = 0.0  # the loops' ratios of their moves to the steps' variance
        self._path_m: dict[int, float] = {}  # graph index -> path flown since the first
        self._last_kf: KeyframeRecord | None = None
        self._map_loops: tuple[LoopEdge, ...] = ()
        self._offset = 0  # graph index = the odometry's keyframe index + offset
        self.segments = Segments()
        self._last_image_ns: int | None = None
        self._reloc_last: RelocCandidate | None = None
        self._reloc_edges: dict[int, list[RelocCandidate]] = {}  # odometry index -> matches
        self._reloc_tried = -1  # the newest keyframe last looked up
        self._jumps = 0  # output jumps at relocalization
        self._last_output: Pose | None = None  # the last corrected pose given out
        self._own_loops: list[LoopConstraint] = []  # this run's loops, for a final smoothing
        self._refined: dict[int, Pose] | None = None  # graph index -> its smoothed pose
        self.map_camera = MapCamera.of(camera)
        if loop_map is not None:
            self._load(loop_map)

    # -- the odometry interface -------------------------------------------------------------
    @property
    def cameras(self) -> tuple[str, ...]:
        return self.odometry.cameras

    def push(self, sample: ImuSample | ImageFrame) -> OdometryState | None:
        if isinstance(sample, ImageFrame) and sample.camera == self._camera.name:
            self._note_image(sample.t_ns)
        state = self.odometry.push(sample)
        self._take_events()
        if state is not None and state.reset_counter != self.segments.current.reset_counter:
            self._new_segment(state.reset_counter, state.t_ns, prior=None, first_pose=state.T_W_B)
        if isinstance(sample, ImageFrame):
            for rec in self.odometry.keyframes():
                self._take(rec)
            if not self.segments.current.joined:
                self._relocalize()
        return None if state is None else self._corrected(state)

    def keyframes(self, *, final: bool = False) -> Sequence[KeyframeRecord]:
        if final:
            for rec in self.odometry.keyframes(final=True):
                self._take(rec)
            self.graph.wait(timeout_s=FINAL_WAIT_S)
        out, self._out = self._out, []
        return out

    def newest_keyframe(self) -> KeyframeRecord | None:
        return self.odometry.newest_keyframe()

    @property
    def events(self) -> tuple[OdometryEvent, ...]:
        """The odometry's events and loop closure's, in the order they happened."""
        self._take_events()
        return tuple(self._events)

    def _take_events(self) -> None:
        new = self.odometry.events[self._odometry_events :]
        self._odometry_events += len(new)
        self._events.extend(new)

    @property
    def last_features(self) -> FrameFeatures | None:
        return self.odometry.last_features

    @property
    def rejected(self) -> Mapping[str, int]:
        return {
            **self.odometry.rejected,
            **{f"loop_{k}": v for k, v in self.graph.rejected.items()},
        }

    def timing(self) -> StageTiming:
        return self.odometry.timing()

    def calibration(self) -> tuple[CameraCalibration, ...]:
        """The wrapped odometry's calibration as it has it now, when it refines one online
        (:class:`~quadnav.odometry.OnlineCalibration`); none otherwise."""
        inner = self.odometry
        return inner.calibration() if isinstance(inner, OnlineCalibration) else ()

    def close(self) -> None:
        """Stop the pose graph's thread and worker (its counts kept in :attr:`stats`)."""
        self.stats.optimizations = self.graph.optimizations
        self.stats.failures = self.graph.failures
        self.stats.last_error = self.graph.last_error
        self.stats.segments = len(self.segments.items)
        self.graph.close()

    def corrected_keyframes(self) -> Trajectory:
        """This run's keyframes (not a loaded map's) as the latest pose graph has them, in time
        order."""
        poses = self.graph.keyframe_poses()
        keep = sorted(
            (self._t_of[k], k) for k in poses
            if k in self._t_of and self._segment_of.get(k) != MAP_FRAME
        )  # fmt: skip
        return Trajectory(
            t_ns=np.array([t for t, _ in keep], dtype=np.int64),
            p_W_B=np.array([poses[k].p_A_B for _, k in keep]).reshape(-1, 3),
            q_W_B_xyzw=np.array([poses[k].R_A_B.as_quat() for _, k in keep]).reshape(-1, 4),
            name="keyframes_loop",
        )

    @property
    def smoothing(self) -> object | None:
        """The wrapped odometry's final smoothing's report, where it has one."""
        return getattr(self.odometry, "smoothing", None)

    def final_trajectory(self) -> Trajectory:
        """Every frame of the run again, not causal: the wrapped odometry's final trajectory
        (:class:`~quadnav.odometry.LoopRefinedTrajectory`) through the keyframe poses of the
        latest pose graph, or, when it smooths its run at the end, with this run's loops as
        factors of that smoothing; an odometry that cannot: the corrected keyframes."""
        inner = self.odometry
        if not isinstance(inner, LoopRefinedTrajectory):
            return self.corrected_keyframes()
        self.graph.wait(timeout_s=FINAL_WAIT_S)
        poses = {
            k - self._offset: p for k, p in self.graph.keyframe_poses().items()
            if self._segment_of.get(k, MAP_FRAME) != MAP_FRAME
        }  # fmt: skip
        final = inner.final_trajectory_with(tuple(self._own_loops), poses)
        self._refined = {k + self._offset: p for k, p in inner.final_keyframe_poses().items()}
        return final

    def step_variances(self) -> dict[int, float] | None:
        """Each of this run's keyframes' step variance, by its time, as the graph's last solve
        gave its sequential edges (times the steps' scale the loops found; None when the
        odometry's covariance is not used)."""
        if not self.config.use_odometry_covariance:
            return None
        scale = self.stats.step_scale
        return {
            self._t_of[k]: (v or 0.0) * scale for k, v in self._step_of.items() if k in self._t_of
        }

    def segment_by_time(self) -> dict[int, int]:
        """Each of this run's keyframes' segment (its frame in the pose graph), by its time."""
        return {t: self._segment_of[k] for k, t in self._t_of.items() if k in self._segment_of}

    def own_places(self) -> list[PlaceEvent]:
        """The places recognised between two keyframes of this run (not a loaded map's, whose
        times are those of the flight that made it)."""
        return [p for p in self.stats.places if self._segment_of.get(p.old) != MAP_FRAME]

    # -- the map ----------------------------------------------------------------------------
    def _load(self, loop_map: LoopMap) -> None:
        """A saved map as the root: its keyframes held in the graph, in the database."""
        if (why := loop_map.camera.mismatch(self.map_camera)) is not None:
            raise LoopError(f"the map was made with another camera ({why})")
        if loop_map.vocabulary != self.detector.database.vocabulary.fingerprint:
            raise LoopError("the map was made with another vocabulary")
        for kf in loop_map.keyframes:
            rec = kf.record
            self.graph.add_pose(rec.index, rec.T_W_B, t_ns=rec.t_ns, reset_counter=MAP_FRAME,
                                fixed=True)  # fmt: skip
            entry = self.detector.database.add_bow(kf.bow, kf.direct)
            self._records[entry] = rec
            self._entry_of[rec.index] = entry
            self._by_index[rec.index] = rec
            self._segment_of[rec.index] = MAP_FRAME
            self._raw[rec.index] = rec.T_W_B
            self._t_of[rec.index] = rec.t_ns
        self._map_loops = loop_map.loops
        self._offset = loop_map.next_index
        self.stats.map_keyframes = len(loop_map.keyframes)
        self.segments.items[:] = []  # a run on a map starts unjoined, at an unknown transform

    def export_map(self) -> LoopMap:
        """The map to save: every keyframe joined to the map (a loaded map's and this run's), at
        its pose in the latest pose graph, its landmarks moved with it, and the loops between
        them. Call after the last keyframes (``keyframes(final=True)``). When the odometry
        smooths its run at the end (``--final-ba``), this run's keyframes are where that
        smoothing, with the loops as factors, put them."""
        self.graph.wait(timeout_s=FINAL_WAIT_S)
        if self._refined is None and isinstance(self.odometry, LoopRefinedTrajectory):
            self.final_trajectory()  # (the smoothing, once: the odometry keeps its result)
        poses = {**self.graph.keyframe_poses(), **(self._refined or {})}
        joined = {s.id for s in self.segments.items if s.joined} | {MAP_FRAME}
        keep = [k for k in sorted(self._by_index) if self._segment_of.get(k) in joined]
        out = []
        for k in keep:
            rec = self._by_index[k]
            T = rec.T_W_B if self._segment_of[k] == MAP_FRAME else poses.get(k)  # a map's: held
            if T is None:
                continue
            move = T @ self._raw[k].inverse()
            rec = replace(rec, index=k, reset_counter=MAP_FRAME, T_W_B=T, image=None,
                          landmarks_W=move @ rec.landmarks_W if len(rec.landmarks_W) else rec.landmarks_W)  # fmt: skip
            entry = self._entry_of[k]
            out.append(MapKeyframe(record=rec, bow=self.detector.database.bow(entry),
                                   direct=self.detector.database.direct(entry)))  # fmt: skip
        kept = {m.record.index for m in out}
        loops = tuple(e for e in (*self._map_loops, *self.graph.loops())
                      if e.old in kept and e.new in kept)  # fmt: skip
        return LoopMap(keyframes=tuple(out), loops=loops, camera=self.map_camera,
                       vocabulary=self.detector.database.vocabulary.fingerprint)  # fmt: skip

    # -- segments ---------------------------------------------------------------------------
    def _note_image(self, t_ns: int) -> None:
        last, self._last_image_ns = self._last_image_ns, t_ns
        if not self.segments.items:  # the first image: the first segment
            self._new_segment(0, t_ns, prior=None, first=True)
            return
        if last is not None and t_ns - last > s_to_ns(self.config.image_gap_s):
            cur = self.segments.current
            prior = self.graph.T_M_O(cur.id) if cur.joined or cur.prior is not None else None
            self._new_segment(cur.reset_counter, t_ns, prior=prior)
            self._event_at(t_ns, "image_gap", f"no image for {(t_ns - last) / NS_PER_S:.2f} s: "
                           f"segment {self.segments.current.id}, relocalizing")  # fmt: skip

    def _new_segment(
        self, reset_counter: int, t_ns: int, *, prior: Pose | None, first: bool = False,
        first_pose: Pose | None = None,
    ) -> None:  # fmt: skip
        """A new segment; after a reset (``first_pose``: the new odometry frame's first pose)
        its frame is taken, until joined, where the output goes on from the last one given
        (gravity-aligned frames: a yaw and a translation), so the output jumps only when the
        segment is joined to the map."""
        root = first and self.stats.map_keyframes == 0
        seg = self.segments.start(reset_counter, t_ns, joined=root, prior=prior)
        if prior is not None:
            self.graph.start_frame(seg.id, prior)
        elif not root and self.segments.items[:-1]:
            guess = self.graph.T_M_O(self.segments.items[-2].id)
            if first_pose is not None and self._last_output is not None:
                guess = continuing_frame(self._last_output, first_pose)
            self.graph.start_frame(seg.id, guess)
        self._reloc_last = None

    def _corrected(self, state: OdometryState) -> OdometryState:
        seg = self.segments.current.id if self.segments.items else 0
        T = self.graph.T_M_O(seg)
        jumps = self.graph.correction().reset_counter + self._jumps
        self._last_output = T @ state.T_W_B
        return replace(
            state, T_W_B=T @ state.T_W_B, v_W_B=T.R_A_B.apply(state.v_W_B),
            reset_counter=state.reset_counter + jumps,
        )  # fmt: skip

    # -- relocalization ---------------------------------------------------------------------
    def _relocalize(self) -> None:
        """Look the odometry's newest keyframe up in the map (once each) and join the segment
        when two matches agree."""
        rec = self.odometry.newest_keyframe()
        if rec is None or rec.index == self._reloc_tried or not self.segments.items:
            return
        self._reloc_tried = rec.index
        seg = self.segments.current
        if rec.reset_counter != seg.reset_counter or rec.t_ns < seg.t_start_ns:
            return  # a keyframe from before the segment began
        query = self._described(rec)
        if query.descriptors is None or len(query.descriptors) == 0:
            return
        desc = query.descriptors if query.described is None else query.descriptors[query.described]
        bow, _ = self.detector.database.transform(desc)
        found = self._reloc_match(query, bow)
        if found is None:
            return
        old, v = found
        assert v.loop is not None
        T_M_Bold = self.graph.pose_of(old.index)
        if T_M_Bold is None:
            return
        T_M_O = four_dof(T_M_Bold @ v.loop.T_Bo_Bq @ rec.T_W_B.inverse())
        cand = RelocCandidate(segment=seg.id, t_ns=rec.t_ns, old=old.index, new=rec.index,
                              T_old_new=v.loop.T_Bo_Bq, cov_4dof=v.loop.cov_4dof, T_M_O=T_M_O,
                              inliers=v.n_pnp)  # fmt: skip
        if seg.prior is not None:
            dm, dr = transform_gap(seg.prior, T_M_O)
            if dm > self.config.relocalize_max_jump_m or dr > self.config.relocalize_max_jump_rad:
                self.stats.relocalize_rejected["jump"] += 1
                return
            self._join(seg, cand, (cand,))  # the frame went on: one match within reach will do
            return
        last, self._reloc_last = self._reloc_last, cand
        if last is None or last.segment != seg.id:
            return
        if cand.t_ns - last.t_ns > s_to_ns(self.config.relocalize_window_s):
            return
        dm, dr = transform_gap(last.T_M_O, cand.T_M_O)
        if dm > self.config.relocalize_agree_m or dr > self.config.relocalize_agree_rad:
            self.stats.relocalize_rejected["disagree"] += 1
            return
        self._join(seg, cand, (last, cand))

    def _reloc_match(
        self, query: KeyframeRecord, bow: BowVector
    ) -> tuple[KeyframeRecord, Verification] | None:
        """The first of the best entries of the database's three best islands in joined
        segments that verifies (islands: the keyframes just before a gap, which look alike,
        take one try, not all three)."""
        joined = {s.id for s in self.segments.items if s.joined} | {MAP_FRAME}
        cfg = self.config.detector
        results = tuple(
            r for r in self.detector.database.query(bow, max_results=cfg.max_results)
            if (old := self._records.get(r.entry)) is not None
            and self._segment_of.get(old.index) in joined
        )  # fmt: skip
        for island in islands(results, cfg.island_gap, cfg.min_island_size)[:3]:
            old = self._records[island.best]
            k = self.config.local_map_keyframes
            near = [
                x for i in range(old.index - k, old.index + k + 1) if (x := self._by_index.get(i))
            ]
            v = verify_place(query, local_map(old, near, self._T_B_C), focal_px=self._focal_px,
                             T_B_C=self._T_B_C, config=self.config.verification)  # fmt: skip
            if v.loop is not None:
                return old, v
            self.stats.relocalize_rejected[v.stage] += 1
        return None

    def _join(
        self, seg: Segment, cand: RelocCandidate, matches: tuple[RelocCandidate, ...]
    ) -> None:
        before = self.graph.T_M_O(seg.id)
        self.graph.set_frame(seg.id, cand.T_M_O)
        seg.joined = True
        dm, dr = transform_gap(before, cand.T_M_O)
        self._jumps += 1
        for m in matches:  # into the graph now if the keyframe is there, else when it comes
            if m.new + self._offset in self._t_of:
                self._add_loop(m.old, m.new + self._offset, m.T_old_new, m.cov_4dof)
            else:
                self._reloc_edges.setdefault(m.new, []).append(m)
        self.stats.joins.append({"t_ns": cand.t_ns, "segment": seg.id, "how": "relocalized",
                                 "map_keyframe": cand.old, "inliers": cand.inliers,
                                 "jump_m": dm, "jump_deg": math.degrees(dr)})  # fmt: skip
        self._event_at(cand.t_ns, "relocalized", f"segment {seg.id} on keyframe {cand.old} "
                       f"({cand.inliers} inliers; output moved {dm:.2f} m, {math.degrees(dr):.1f} deg)")  # fmt: skip

    # -- each finished keyframe -------------------------------------------------------------
    def _take(self, odo: KeyframeRecord) -> None:
        self._out.append(odo)
        if not self.segments.items:  # a keyframe before any image: cannot be
            self._new_segment(odo.reset_counter, odo.t_ns, prior=None, first=True)
        seg = self.segments.of(odo.reset_counter, odo.t_ns)
        rec = replace(odo, index=odo.index + self._offset)
        k_new = rec.index
        self._t_of[k_new] = rec.t_ns
        self._segment_of[k_new] = seg.id
        self._raw[k_new] = rec.T_W_B
        step_var = self._step_var(rec, seg.id)
        self._step_of[k_new] = step_var
        self._note_steps(k_new, seg.id, step_var)
        self._note_path(rec, seg.id)
        self.stats.keyframes += 1
        self.graph.add_pose(k_new, rec.T_W_B, t_ns=rec.t_ns, reset_counter=seg.id,
                            step_var=step_var)  # fmt: skip
        for m in self._reloc_edges.pop(odo.index, []):
            self._add_loop(m.old, k_new, m.T_old_new, m.cov_4dof)
        query = self._described(rec)
        if query.descriptors is None or len(query.descriptors) == 0:
            self.stats.undescribed += 1
            return
        desc = query.descriptors if query.described is None else query.descriptors[query.described]
        found = self.detector.push(desc)
        self._records[found.entry] = rec
        self._entry_of[k_new] = found.entry
        self._by_index[k_new] = rec
        if not found.detected or found.match is None:
            return
        old = self._records[found.match]
        old_seg = self._segment_of.get(old.index)
        joined = {s.id for s in self.segments.items if s.joined} | {MAP_FRAME}
        if old_seg != seg.id and old_seg not in joined:
            return  # two segments not in the map: nothing to tie them to
        if k_new - self._last_loop < self.config.min_keyframes_between:
            return
        self._verify_loop(rec, query, old, same_frame=old_seg == seg.id)

    def _verify_loop(
        self, rec: KeyframeRecord, query: KeyframeRecord, old: KeyframeRecord, *, same_frame: bool
    ) -> None:
        self.stats.recognised += 1
        k = self.config.local_map_keyframes
        near = [r for i in range(old.index - k, old.index + k + 1) if (r := self._by_index.get(i))]
        local = local_map(old, near, self._T_B_C)
        v = verify_place(
            query, local, focal_px=self._focal_px, T_B_C=self._T_B_C,
            config=self.config.verification,
        )  # fmt: skip
        place = PlaceEvent(old=old.index, new=rec.index, t_old_ns=old.t_ns, t_new_ns=rec.t_ns,
                           stage=v.stage, n_matches=v.n_matches, n_fundamental=v.n_fundamental,
                           n_pnp=v.n_pnp)  # fmt: skip
        if v.loop is None:
            self._reject(rec, place, f"{v.stage} ({v.n_matches} matches, {v.n_fundamental} F, "
                         f"{v.n_pnp} PnP inliers)")  # fmt: skip
            return
        drift = self._implied_drift(rec, old, v.loop) if same_frame else None
        if drift is not None:
            self._reject(rec, replace(place, stage="drift"), f"drift ({drift})")
            return
        self.stats.accepted += 1
        T = v.loop.T_Bo_Bq
        sigma = np.sqrt(np.clip(np.diag(v.loop.cov_4dof), 0.0, None))
        self.stats.places.append(replace(
            place, T_old_new=(*T.p_A_B.tolist(), *T.R_A_B.as_quat().tolist()),
            sigma_4dof=tuple(sigma.tolist()),
        ))  # fmt: skip
        self._last_loop = rec.index
        matches = (local.ids[v.loop.old_rows], query.xy[v.loop.query_rows])
        self._add_loop(old.index, rec.index, T, v.loop.cov_4dof, matches)
        seg = self.segments.items[self._segment_of[rec.index]]
        if not seg.joined and self._in_map(old.index):  # (a loop inside it joins nothing)
            seg.joined = True
            self.stats.joins.append({"t_ns": rec.t_ns, "segment": seg.id, "how": "loop",
                                     "map_keyframe": old.index, "inliers": v.n_pnp})  # fmt: skip
        self._event(rec, "loop", f"keyframe {old.index}: {v.n_pnp} inliers, yaw "
                    f"{v.yaw_deg:.1f} deg, {v.translation_m:.2f} m apart")  # fmt: skip

    def _in_map(self, index: int) -> bool:
        """Whether keyframe ``index`` is joined to the map (a loaded map's, or of a joined
        segment)."""
        seg = self._segment_of.get(index)
        return seg == MAP_FRAME or (seg is not None and self.segments.items[seg].joined)

    def _add_loop(
        self, old: int, new: int, T_old_new: Pose, cov_4dof: FloatArray,
        matches: tuple[IntArray, FloatArray] | None = None,
    ) -> None:  # fmt: skip
        c = self.config
        floor = np.diag([c.loop_floor_m**2] * 3 + [c.loop_floor_yaw_rad**2])
        cov = cov_4dof + floor if c.graph.kind == "4dof" else None
        self._learn_step_scale(old, new, T_old_new, cov_4dof[:3, :3] + floor[:3, :3])
        taken = self.graph.add_loop(LoopEdge(old=old, new=new, T_old_new=T_old_new, cov=cov))
        if taken and MAP_FRAME not in (self._segment_of.get(old), self._segment_of.get(new)):
            try:
                self._own_loops.append(loop_constraint(
                    old - self._offset, new - self._offset, T_old_new, cov_4dof + floor, matches
                ))  # fmt: skip
            except QuadnavError:  # (a covariance that is none: the pose graph has the loop)
                self.stats.unsmoothable += 1

    def _learn_step_scale(self, old: int, new: int, T_old_new: Pose, cov_loop: FloatArray) -> None:
        """A loop within a segment of this run measures the odometry's drift between its
        keyframes: its squared move beyond its own variance, over the steps' variance between
        them, at most ``max_step_scale``. Averaged over the loops, pulled towards 1, the
        steps' scale (see :class:`LoopConfig`), given to the graph."""
        c = self.config
        if not (c.learn_step_scale and c.use_odometry_covariance):
            return
        if old not in self._cum or new not in self._cum:
            return
        if self._segment_of.get(old) != self._segment_of.get(new):
            return
        steps = 3.0 * (self._cum[new] - self._cum[old])
        if not (math.isfinite(steps) and steps > 0.0):
            return
        rel = self._raw[old].inverse() @ self._raw[new]
        beyond = float(np.sum((rel.p_A_B - T_old_new.p_A_B) ** 2) - np.trace(cov_loop))
        if not math.isfinite(beyond):
            return
        self._scale_sum += min(max(beyond / steps, 0.0), c.max_step_scale)
        st = self.stats
        st.step_scale_loops += 1
        prior = c.step_scale_prior_loops
        st.step_scale = max((self._scale_sum + prior) / (st.step_scale_loops + prior), 1.0)
        self.graph.scale_steps(st.step_scale)

    def _reject(self, rec: KeyframeRecord, place: PlaceEvent, why: str) -> None:
        self.stats.rejected[place.stage] += 1
        self.stats.places.append(place)
        self._event(rec, "loop_rejected", f"keyframe {place.old}: {why}")

    def _note_steps(self, k: int, segment: int, step_var: float | None) -> None:
        """Keyframe ``k``'s step variances summed since its segment's first (what a loop
        within the segment compares its move with)."""
        last = self._last_kf
        same = last is not None and self._segment_of.get(last.index) == segment
        base = self._cum.get(last.index, 0.0) if same and last is not None else 0.0
        self._cum[k] = base + (step_var or 0.0)

    def _note_path(self, rec: KeyframeRecord, segment: int) -> None:
        last = self._last_kf
        step = 0.0
        if last is not None and self._segment_of.get(last.index) == segment:
            step = float(np.linalg.norm(rec.T_W_B.p_A_B - last.T_W_B.p_A_B))
        before = self._path_m.get(last.index, 0.0) if last is not None else 0.0
        self._path_m[rec.index] = before + step
        self._last_kf = rec

    def _step_var(self, rec: KeyframeRecord, segment: int) -> float | None:
        """The odometry's position variance (m^2, the mean of its axes) added since the
        keyframe before in this segment (0 for a segment's first; None when the odometry's
        covariance is not used). From the keyframes' steps (:class:`KeyframeStep`) where the
        odometry gives them: summed along the segment (:meth:`_note_steps`), so a step from a
        keyframe before the last one counts only what it adds. Else the growth of the position marginal, which
        also swings with the heading's and scale's shared error (see :class:`KeyframeStep`)."""
        if not self.config.use_odometry_covariance:
            return None
        last = self._last_kf
        if last is None or self._segment_of.get(last.index) != segment:
            return 0.0
        step = rec.step
        after = None if step is None else step.after + self._offset
        if step is not None and after in self._cum and self._segment_of.get(after) == segment:
            # the sum to this keyframe less the sum to the one before (:meth:`_note_steps`)
            grow = self._cum[after] + float(np.trace(step.cov_W)) / 3.0 - self._cum[last.index]
        else:
            grow = (np.trace(rec.cov_pose[3:, 3:]) - np.trace(last.cov_pose[3:, 3:])) / 3.0
        return float(grow) if math.isfinite(grow) and grow > 0.0 else 0.0

    def _implied_drift(
        self, rec: KeyframeRecord, old: KeyframeRecord, loop: LoopMatch
    ) -> str | None:
        """Why a verified loop within one segment implies more drift than the odometry can have
        made since the old keyframe (by the path flown, or by the odometry's covariance), or
        None."""
        c = self.config
        move = loop.T_Wo_Bq.p_A_B - rec.T_W_B.p_A_B
        moved = float(np.linalg.norm(move))
        flown = self._path_m.get(rec.index, 0.0) - self._path_m.get(old.index, 0.0)
        allowed = c.max_drift_m + c.max_drift_fraction * max(flown, 0.0)
        if moved > allowed:
            return f"{moved:.2f} m after {flown:.1f} m flown, at most {allowed:.2f} m"
        if c.max_drift_chi2 <= 0.0 or not c.use_odometry_covariance:
            return None
        R_o = old.T_W_B.R_A_B.as_matrix()
        R_n = rec.T_W_B.R_A_B.as_matrix()
        cov = (
            R_o @ (old.cov_pose[3:, 3:] + loop.cov_4dof[:3, :3]) @ R_o.T
            + R_n @ rec.cov_pose[3:, 3:] @ R_n.T + np.eye(3) * c.loop_floor_m**2
        )  # fmt: skip
        try:
            chi2 = float(move @ np.linalg.solve(cov, move))
        except np.linalg.LinAlgError:
            return None
        if not math.isfinite(chi2) or chi2 <= c.max_drift_chi2:
            return None
        return (
            f"{moved:.2f} m, chi-square {chi2:.1f} against the odometry's covariance "
            f"(at most {c.max_drift_chi2:g})"
        )

    def _described(self, rec: KeyframeRecord) -> KeyframeRecord:
        """The keyframe with ``extra_corners`` corners of its own image described too (ids
        below zero, no landmarks): what recognition and verification see of it."""
        n = self.config.extra_corners
        if n == 0 or rec.image is None:
            return rec
        try:
            image = rec.image.image()
        except QuadnavError:
            self.stats.unreadable += 1
            return rec
        uv, desc = describe_image(image, max_corners=n)
        if len(uv) == 0:
            return rec
        xy = self._as_record_has_it(rec, uv)
        own = (
            rec.descriptors
            if rec.descriptors is not None
            else np.zeros((len(rec.ids), 32), np.uint8)
        )
        ok = rec.described if rec.described is not None else np.ones(len(rec.ids), bool)
        return replace(
            rec,
            ids=np.concatenate([rec.ids, -1 - np.arange(len(uv), dtype=np.int64)]),
            uv_px=np.vstack([rec.uv_px, uv]), xy=np.vstack([rec.xy, xy]),
            descriptors=np.vstack([own, desc]), described=np.concatenate([ok, np.ones(len(uv), bool)]),
        )  # fmt: skip

    def _as_record_has_it(self, rec: KeyframeRecord, uv: FloatArray) -> FloatArray:
        """Normalised coordinates of pixels ``uv`` as the keyframe's own are: undistorted with
        the stated lens, then through the affine map that takes the keyframe's tracked corners
        so undistorted to its coordinates (the odometry's intrinsics, refined online)."""
        undistort = self._camera.camera.undistort_pixels
        xy = undistort(uv, P=np.eye(3)).reshape(-1, 2)
        if len(rec.ids) < 6:
            return xy
        own = undistort(rec.uv_px, P=np.eye(3)).reshape(-1, 2)
        A = np.column_stack([own, np.ones(len(own))])
        M, *_ = np.linalg.lstsq(A, rec.xy, rcond=None)
        return np.asarray(np.column_stack([xy, np.ones(len(xy))]) @ M, dtype=np.float64)

    def _event(self, rec: KeyframeRecord, kind: EventKind, detail: str) -> None:
        self._take_events()
        self._events.append(OdometryEvent(t_ns=rec.t_ns, kind=kind, detail=detail))

    def _event_at(self, t_ns: int, kind: EventKind, detail: str) -> None:
        self._take_events()
        self._events.append(OdometryEvent(t_ns=t_ns, kind=kind, detail=detail))
