"""A VINS-Mono-style feature tracker (thesis 003 sec. 3.1.1) and the statistics of its tracks.

Per frame: pyramidal Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``) moves the previous frame's
features into the new image; a feature is dropped when KLT loses it, when it leaves the image
border, when tracking it back to the previous image misses its start by more than
``fb_threshold_px`` (the forward-backward check of VINS-Fusion), or when it is an outlier of a
fundamental matrix fitted by RANSAC on undistorted pixels (VINS' ``rejectWithF``). Given the
camera's rotation since the previous frame (the gyro's), KLT starts each feature where that
rotation alone would move it (VINS-Fusion's and OpenVINS' predicted flow), over
``predicted_pyramid_levels`` levels: a fast turn then stays within the search. The survivors
are kept longest-track first with at least ``min_distance_px`` between any two (VINS'
``setMask``), and Shi-Tomasi corners (``cv2.goodFeaturesToTrack``) outside circles of that radius
top the frame up to ``max_features``. Each feature has an id for life and a length: the number of
frames it has been seen in.

A blank frame is not an error: it has no features and is counted. An image the tracker cannot use
(empty, not 8-bit, a wrong shape, a size that changes) is a one-line :class:`VisionError`.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import json
import math
import sys
import time
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import VisionError
from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose
from quadnav.messages import ImageFrame
from quadnav.vision.tracker_config import TrackerConfig

__all__ = [
    "FeatureTracker",
    "FrameCounts",
    "Spread",
    "StageTimes",
    "StereoGeometry",
    "StereoMatches",
    "TrackStats",
    "TrackStatsAccumulator",
    "TrackedFrame",
    "TrackerConfig",
    "as_grey",
    "fundamental_inliers",
    "keep_freed_memory",
    "rotated_pixels",
    "track_sequence",
    "track_stereo",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]
Image = NDArray[np.uint8]

#: VINS' inBorder: a tracked point must lie this many pixels inside the image.
BORDER_PX = 1
#: RANSAC confidence of the fundamental-matrix fit (VINS: 0.99).
RANSAC_CONFIDENCE = 0.99
#: The fewest correspondences a fundamental matrix is fitted to (the 8-point algorithm).
MIN_RANSAC_POINTS = 8
#: glibc's ``mallopt`` parameters and the values the tracker sets (see :func:`keep_freed_memory`).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD_BYTES = 32 << 20
TRIM_THRESHOLD_BYTES = 64 << 20


@functools.cache
def keep_freed_memory() -> bool:
    """Let the process keep the memory OpenCV frees between frames (glibc only; once per
    process; whether it was set). Each corner detection and KLT call allocates some 15 MB of
    temporary buffers (the corner response, the image pyramids); by default glibc maps the large
    ones afresh from the system and returns them when freed, so each frame pays for faulting in
    and zeroing them again: on 752x480 frames, 60 % of the detection's time and a third of the
    tracker's. Here allocations under ``MMAP_THRESHOLD_BYTES`` come from the heap and freed
    memory is handed back only beyond ``TRIM_THRESHOLD_BYTES``: the process holds at most that
    much more than it uses."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc
        return False
    return bool(
        mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
        and mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class FrameCounts:
    """What happened to the previous frame's features in this one (``previous`` = ``tracked`` +
    the five losses) and how many corners were added."""

    previous: int
    tracked: int
    lost_klt: int
    lost_border: int
    lost_fb: int
    lost_ransac: int
    lost_spacing: int
    new: int


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackedFrame:
    """The features of one frame: ``ids`` (int64, unique for the tracker's life), ``pixels``
    (N, 2) where they are in the image, ``pixels_undistorted`` (N, 2) the same without lens
    distortion (the camera matrix unchanged; equal to ``pixels`` without a camera),
    ``track_lengths`` (frames each id has been seen in, this one included) and ``is_new``."""

    t_ns: int
    ids: IntArray
    pixels: FloatArray
    pixels_undistorted: FloatArray
    track_lengths: IntArray
    is_new: BoolArray
    counts: FrameCounts

    def __len__(self) -> int:
        return int(self.ids.size)


@dataclass(frozen=True, slots=True, kw_only=True)
class StageTimes:
    """Wall time (s) of each stage of the last :meth:`FeatureTracker.track`."""

    prepare_s: float = 0.0
    klt_s: float = 0.0
    fb_s: float = 0.0
    ransac_s: float = 0.0
    detect_s: float = 0.0

    @property
    def total_s(self) -> float:
        return self.prepare_s + self.klt_s + self.fb_s + self.ransac_s + self.detect_s


@dataclass(slots=True)
class _State:
    """The previous frame: its image and its features."""

    image: Image
    shape: tuple[int, int]
    t_ns: int
    pts: FloatArray
    ids: IntArray
    lengths: IntArray
    undistorted: FloatArray


def _clahe() -> cv2.CLAHE:
    """VINS-Mono's equalizer: CLAHE with clip limit 3 over 8x8 tiles."""
    return cv2.createCLAHE(clipLimit=3.0, tileGridSize=(8, 8))


def _empty_int() -> IntArray:
    return np.zeros(0, np.int64)


@dataclass(slots=True)
class _Survivors:
    """Features being carried from the previous frame into this one."""

    prev: FloatArray
    cur: FloatArray
    ids: IntArray
    lengths: IntArray
    losses: dict[str, int] = field(default_factory=dict)

    def keep(self, mask: BoolArray, reason: str) -> None:
        self.losses[reason] = self.losses.get(reason, 0) + int((~mask).sum())
        self.prev, self.cur = self.prev[mask], self.cur[mask]
        self.ids, self.lengths = self.ids[mask], self.lengths[mask]


def as_grey(image: object, what: str = "image") -> Image:
    """An 8-bit grey (H, W) image from a grey, (H, W, 1), BGR or BGRA one; anything else is a
    one-line :class:`VisionError`."""
    if not isinstance(image, np.ndarray):
        raise VisionError(f"{what} must be a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise VisionError(f"{what} must be 8-bit (uint8), got {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3 and image.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        image = cv2.cvtColor(np.ascontiguousarray(image), code)
    if image.ndim != 2:
        raise VisionError(
            f"{what} must be (H, W) grey or (H, W, 3) BGR or (H, W, 4) BGRA, got shape {image.shape}"
        )
    if image.size == 0:
        raise VisionError(f"{what} is empty (shape {image.shape})")
    return np.ascontiguousarray(image)


def _in_border(pts: FloatArray, shape: tuple[int, int]) -> BoolArray:
    h, w = shape
    x, y = np.rint(pts[:, 0]), np.rint(pts[:, 1])
    ok: BoolArray = (
        np.isfinite(pts).all(axis=1)
        & (x >= BORDER_PX)
        & (x < w - BORDER_PX)
        & (y >= BORDER_PX)
        & (y < h - BORDER_PX)
    )
    return ok


def fundamental_inliers(
    prev_px: FloatArray,
    cur_px: FloatArray,
    *,
    threshold_px: float,
    camera: PinholeCamera | None = None,
) -> BoolArray:
    """Which correspondences fit a fundamental matrix found by RANSAC (``threshold_px``: the
    largest distance to an epipolar line), on undistorted pixels when a camera is given. With
    fewer than 8 correspondences, or no matrix found, all are kept."""
    n = len(prev_px)
    if n < MIN_RANSAC_POINTS:
        return np.ones(n, bool)
    a, b = prev_px, cur_px
    if camera is not None and camera.distorted:
        a, b = camera.undistort_pixels(a), camera.undistort_pixels(b)
    _, status = cv2.findFundamentalMat(
        a.astype(np.float32),
        b.astype(np.float32),
        cv2.FM_RANSAC,
        float(threshold_px),
        RANSAC_CONFIDENCE,
    )
    if status is None:
        return np.ones(n, bool)
    out: BoolArray = status.ravel().astype(bool)
    return out


def rotated_pixels(
    camera: PinholeCamera, px: FloatArray, undistorted_px: FloatArray, R_a_b: FloatArray
) -> FloatArray:
    """Where pixels ``px`` (``undistorted_px`` without the lens) of camera pose ``a`` fall in the
    image of pose ``b`` when the camera only rotated, by ``R_a_b`` (b's orientation in a): KLT's
    prediction from the gyro. A point that would fall behind the camera keeps its pixel."""
    u = np.asarray(undistorted_px, np.float64)
    K = camera.K
    y = (u[:, 1] - K[1, 2]) / K[1, 1]
    x = (u[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    rays = np.column_stack([x, y, np.ones(len(u))]) @ np.asarray(R_a_b)  # R_a_b^T f, per row
    ahead = rays[:, 2] > 1e-3
    out = np.array(px, np.float64)
    if ahead.any():
        out[ahead] = camera.project(rays[ahead])
    return out


def _klt(
    img_a: Image,
    img_b: Image,
    pts: FloatArray,
    cfg: TrackerConfig,
    guess: FloatArray | None = None,
    levels: int | None = None,
) -> tuple[FloatArray, BoolArray]:
    """Pyramidal KLT of ``pts`` from image ``a`` into image ``b`` (from ``guess`` when given,
    over ``levels`` pyramid levels, default the config's): new positions and status. (OpenCV's
    Python binding takes no prebuilt pyramid, so each call builds both images' pyramids.)"""
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, cfg.klt_iterations, 0.01)
    p0 = pts.astype(np.float32).reshape(-1, 1, 2)
    flags = 0
    p1 = None
    if guess is not None:
        p1 = guess.astype(np.float32).reshape(-1, 1, 2).copy()
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    nxt, status, _ = cv2.calcOpticalFlowPyrLK(
        img_a,
        img_b,
        p0,
        p1,  # type: ignore[arg-type, unused-ignore]
        winSize=(cfg.window_px, cfg.window_px),
        maxLevel=cfg.pyramid_levels if levels is None else levels,
        criteria=crit,
        flags=flags,
    )
    return nxt.reshape(-1, 2).astype(np.float64), status.ravel().astype(bool)


def _squared_distances(a: FloatArray, b: FloatArray) -> FloatArray:
    """The squared distance of each point of ``a`` (N, 2) to each of ``b`` (M, 2): (N, M),
    ``dx * dx + dy * dy`` (as einsum's sum over the last axis gives it, to the bit, at a
    seventh of its cost for 130 points)."""
    dx = a[:, 0, None] - b[None, :, 0]
    dy = a[:, 1, None] - b[None, :, 1]
    out: FloatArray = dx * dx + dy * dy
    return out


def _spaced(pts: FloatArray, order: IntArray, min_dist: float) -> BoolArray:
    """Greedy in ``order``: keep a point when no kept one is closer than ``min_dist``. A point
    with no neighbour that close is kept whatever the order, so the greedy pass runs over the
    few that have one (tracked features mostly stay apart)."""
    keep = np.ones(len(pts), bool)
    if len(pts) < 2:
        return keep
    near: BoolArray = np.asarray(_squared_distances(pts, pts) < min_dist * min_dist)
    np.fill_diagonal(near, False)
    crowded: BoolArray = np.asarray(near.any(axis=1))
    if not crowded.any():
        return keep
    free = np.ones(len(pts), bool)
    for i in order[crowded[order]].tolist():
        if free[i]:
            free &= ~near[i]
        else:
            keep[i] = False
    return keep


def _detect(img: Image, kept: FloatArray, n_want: int, cfg: TrackerConfig) -> FloatArray:
    """Up to ``n_want`` Shi-Tomasi corners at least ``min_distance_px`` from one another and
    from the ``kept`` features (VINS' mask of circles around them)."""
    if n_want <= 0:
        return np.zeros((0, 2))
    mask = np.full(img.shape, 255, np.uint8)
    r = math.ceil(cfg.min_distance_px)
    for x, y in np.rint(kept).astype(int).tolist():  # (Python ints: no numpy scalars)
        cv2.circle(mask, (x, y), r, 0, -1)
    corners = cv2.goodFeaturesToTrack(
        img, n_want, cfg.quality_level, cfg.min_distance_px, mask=mask, blockSize=3
    )
    if corners is None:
        return np.zeros((0, 2))
    new = corners.reshape(-1, 2).astype(np.float64)
    if len(kept) and len(new):  # the raster circle is approximate: the exact distance decides
        near = _squared_distances(new, kept).min(axis=1) < cfg.min_distance_px**2
        new = new[~near]
    new = new[_in_border(new, (img.shape[0], img.shape[1]))]
    return new


class FeatureTracker:
    """Tracks corners from frame to frame (see the module's docstring). ``camera`` (optional)
    undistorts the pixels the RANSAC check and ``pixels_undistorted`` use; images must then have
    its size."""

    def __init__(
        self, config: TrackerConfig | None = None, camera: PinholeCamera | None = None
    ) -> None:
        self.config = config or TrackerConfig()
        self.camera = camera
        keep_freed_memory()
        self.last_times = StageTimes()
        self._state: _State | None = None
        self._next_id = 0
        self._clahe = _clahe()

    def reset(self) -> None:
        """Forget the previous frame (ids keep counting up)."""
        self._state = None

    def _prepare(self, t_ns: int, image: object) -> Image:
        img = as_grey(image)
        shape = (img.shape[0], img.shape[1])
        side = self.config.window_px
        if min(shape) < side:
            raise VisionError(
                f"image {shape[1]}x{shape[0]} is smaller than the tracker window_px {side}"
            )
        cam = self.camera
        if cam is not None and shape != (cam.height, cam.width):
            raise VisionError(
                f"image is {shape[1]}x{shape[0]} but the camera is {cam.width}x{cam.height}"
            )
        st = self._state
        if st is not None and shape != st.shape:
            raise VisionError(
                f"image size changed from {st.shape[1]}x{st.shape[0]} to {shape[1]}x{shape[0]}"
            )
        if st is not None and t_ns <= st.t_ns:
            raise VisionError(f"frame t_ns {t_ns} is not after the previous one ({st.t_ns})")
        if self.config.equalize:
            return np.asarray(self._clahe.apply(img), np.uint8)
        # kept as the next frame's previous image: a copy, should the caller reuse its buffer
        return img.copy() if img is image else img

    def _carry(
        self, st: _State, img: Image, times: dict[str, float], R_prev_cur: FloatArray | None
    ) -> _Survivors:
        """The previous features through KLT (from their rotated pixels when the rotation is
        given), the border, the forward-backward check and RANSAC."""
        cfg = self.config
        s = _Survivors(st.pts, st.pts, st.ids, st.lengths)
        if len(st.pts) == 0:
            return s
        t0 = time.perf_counter()
        guess, levels = None, None
        if R_prev_cur is not None and self.camera is not None:
            guess = rotated_pixels(self.camera, st.pts, st.undistorted, R_prev_cur)
            levels = cfg.predicted_pyramid_levels
        cur, ok = _klt(st.image, img, st.pts, cfg, guess=guess, levels=levels)
        s.cur = cur
        s.keep(ok, "klt")
        s.keep(_in_border(s.cur, st.shape), "border")
        t1 = time.perf_counter()
        times["klt_s"] = t1 - t0
        if cfg.forward_backward and len(s.cur):
            back, ok_b = _klt(img, st.image, s.cur, cfg, guess=s.prev, levels=cfg.fb_pyramid_levels)
            err = np.linalg.norm(back - s.prev, axis=1)
            s.keep(ok_b & (err <= cfg.fb_threshold_px), "fb")
        t2 = time.perf_counter()
        times["fb_s"] = t2 - t1
        if cfg.ransac:
            inl = fundamental_inliers(
                s.prev, s.cur, threshold_px=cfg.ransac_threshold_px, camera=self.camera
            )
            s.keep(inl, "ransac")
        times["ransac_s"] = time.perf_counter() - t2
        return s

    def track(
        self, t_ns: int, image: object, *, R_prev_cur: FloatArray | None = None
    ) -> TrackedFrame:
        """The features of ``image`` taken at ``t_ns`` (after the previous frame's); with
        ``R_prev_cur``, the camera's rotation since the previous frame (this frame's orientation
        in the previous one's, from the gyro), KLT starts from the features' rotated pixels
        (without a camera the rotation is not used)."""
        cfg = self.config
        times: dict[str, float] = {}
        t0 = time.perf_counter()
        img = self._prepare(int(t_ns), image)
        times["prepare_s"] = time.perf_counter() - t0
        st = self._state
        if st is None:
            s = _Survivors(np.zeros((0, 2)), np.zeros((0, 2)), _empty_int(), _empty_int())
        else:
            s = self._carry(st, img, times, R_prev_cur)
        n_prev = 0 if st is None else len(st.pts)
        t1 = time.perf_counter()
        lengths = s.lengths + 1
        order = np.argsort(-lengths, kind="stable")  # longest tracks keep their place
        s.lengths = lengths
        s.keep(_spaced(s.cur, order, cfg.min_distance_px), "spacing")
        missing = cfg.max_features - len(s.cur)
        # a few missing corners wait for more (the detector costs as much for one as for 50)
        wanted = missing if st is None or missing >= cfg.detect_min_new else 0
        new = _detect(img, s.cur, wanted, cfg)
        times["detect_s"] = time.perf_counter() - t1
        new_ids = np.arange(self._next_id, self._next_id + len(new), dtype=np.int64)
        self._next_id += len(new)
        pts = np.vstack([s.cur, new])
        ids = np.concatenate([s.ids, new_ids])
        lens = np.concatenate([s.lengths, np.ones(len(new), np.int64)])
        und = pts if self.camera is None or not len(pts) else self.camera.undistort_pixels(pts)
        shape = (img.shape[0], img.shape[1])
        self._state = _State(img, shape, int(t_ns), pts, ids, lens, und)
        self.last_times = StageTimes(**times)
        counts = FrameCounts(
            previous=n_prev,
            tracked=len(s.cur),
            lost_klt=s.losses.get("klt", 0),
            lost_border=s.losses.get("border", 0),
            lost_fb=s.losses.get("fb", 0),
            lost_ransac=s.losses.get("ransac", 0),
            lost_spacing=s.losses.get("spacing", 0),
            new=len(new),
        )
        for a in (pts, ids, lens, und):  # shared with the tracker's state: read-only
            a.flags.writeable = False
        return TrackedFrame(
            t_ns=int(t_ns),
            ids=ids,
            pixels=pts,
            pixels_undistorted=und,
            track_lengths=lens,
            is_new=np.concatenate([np.zeros(len(s.cur), bool), np.ones(len(new), bool)]),
            counts=counts,
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class Spread:
    """Mean, standard deviation, median, minimum and maximum of a per-frame quantity (all 0 when
    there is no value, with ``n`` = 0)."""

    n: int
    mean: float
    std: float
    median: float
    min: float
    max: float

    @classmethod
    def of(cls, values: Iterable[float]) -> Spread:
        v = np.asarray(list(values), dtype=np.float64)
        if v.size == 0:
            return cls(n=0, mean=0.0, std=0.0, median=0.0, min=0.0, max=0.0)
        return cls(
            n=int(v.size),
            mean=float(v.mean()),
            std=float(v.std()),
            median=float(np.median(v)),
            min=float(v.min()),
            max=float(v.max()),
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackStats:
    """Tracks over a sequence of ``n_frames``.

    Track lengths are in frames. ``track_length`` counts every track: those that ended and those
    still alive at the last frame (whose length is cut short by the sequence's end);
    ``ended_track_length`` only those that ended before it. ``fraction_tracked`` is, per pair of
    consecutive frames k, k+1, the features of frame k still tracked in frame k+1 over the
    features of frame k (frames k without features give no value). The ``lost_*`` totals say
    which check dropped them (see :class:`FrameCounts`)."""

    n_frames: int
    n_tracks: int
    n_alive_at_end: int
    track_length: Spread
    ended_track_length: Spread
    fraction_tracked: Spread
    features_per_frame: Spread
    new_per_frame: Spread
    frames_without_features: int
    lost_klt: int
    lost_border: int
    lost_fb: int
    lost_ransac: int
    lost_spacing: int

    def to_json(self) -> dict[str, object]:
        """A flat-enough record for ``metrics.json`` (spreads as nested objects)."""
        out: dict[str, object] = asdict(self)
        return out

    def dumps(self) -> str:
        return json.dumps(self.to_json(), indent=2)


class TrackStatsAccumulator:
    """Builds :class:`TrackStats` frame by frame (holds one int per live track, not images)."""

    def __init__(self) -> None:
        self._alive: dict[int, int] = {}
        self._ended: list[int] = []
        self._fraction: list[float] = []
        self._features: list[int] = []
        self._new: list[int] = []
        self._lost = dict.fromkeys(("klt", "border", "fb", "ransac", "spacing"), 0)

    def add(self, frame: TrackedFrame) -> None:
        c = frame.counts
        if self._features and self._features[-1] > 0:
            self._fraction.append(c.tracked / self._features[-1])
        self._features.append(len(frame))
        self._new.append(c.new)
        for k in self._lost:
            self._lost[k] += getattr(c, f"lost_{k}")
        now = dict(zip(frame.ids.tolist(), frame.track_lengths.tolist(), strict=True))
        self._ended.extend(n for i, n in self._alive.items() if i not in now)
        self._alive = now

    def result(self) -> TrackStats:
        alive = list(self._alive.values())
        return TrackStats(
            n_frames=len(self._features),
            n_tracks=len(self._ended) + len(alive),
            n_alive_at_end=len(alive),
            track_length=Spread.of(self._ended + alive),
            ended_track_length=Spread.of(self._ended),
            fraction_tracked=Spread.of(self._fraction),
            features_per_frame=Spread.of(self._features),
            new_per_frame=Spread.of(self._new),
            frames_without_features=sum(n == 0 for n in self._features),
            lost_klt=self._lost["klt"],
            lost_border=self._lost["border"],
            lost_fb=self._lost["fb"],
            lost_ransac=self._lost["ransac"],
            lost_spacing=self._lost["spacing"],
        )


#: Frame period given to images that come without a time (20 Hz).
DEFAULT_PERIOD_NS = 50_000_000


def _timed(images: Iterable[object]) -> Iterator[tuple[int, object]]:
    """(t_ns, pixels) of images, ``(t_ns, image)`` pairs or :class:`ImageFrame` messages (loaded
    one at a time); bare images are 20 Hz from 0."""
    for k, item in enumerate(images):
        if isinstance(item, ImageFrame):
            yield item.t_ns, item.image()
        elif isinstance(item, tuple) and len(item) == 2:
            yield int(item[0]), item[1]
        else:
            yield k * DEFAULT_PERIOD_NS, item


def track_sequence(
    images: Iterable[object],
    config: TrackerConfig | None = None,
    camera: PinholeCamera | None = None,
) -> TrackStats:
    """Track a sequence (an iterator of images, ``(t_ns, image)`` pairs or ``ImageFrame``s,
    consumed one frame at a time) and return its :class:`TrackStats`."""
    tracker = FeatureTracker(config, camera)
    acc = TrackStatsAccumulator()
    for t_ns, img in _timed(images):
        acc.add(tracker.track(t_ns, img))
    return acc.result()


@dataclass(frozen=True, slots=True, kw_only=True)
class StereoGeometry:
    """A calibrated (not rectified) stereo pair: both lenses and ``T_L_R``, the pose of the right
    camera in the left one (``T_B_CL.inverse() @ T_B_CR`` from a rig)."""

    left: PinholeCamera
    right: PinholeCamera
    T_L_R: Pose

    def at_infinity(self, left_px: FloatArray) -> FloatArray:
        """Where left pixels of points far away fall in the right image (KLT's first guess)."""
        rays = _normalized(self.left, left_px) @ self.T_L_R.R_A_B.as_matrix()  # R_R_L @ ray
        return self.right.project(rays)

    def epipolar_error_px(self, left_px: FloatArray, right_px: FloatArray) -> FloatArray:
        """Distance (left-image pixels) of each left point to the epipolar line of its match."""
        a = _normalized(self.left, left_px)
        b = _normalized(self.right, right_px)
        t = self.T_L_R.p_A_B
        tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
        lines = b @ (tx @ self.T_L_R.R_A_B.as_matrix()).T  # E x_R, one line per row
        d = np.abs(np.einsum("ij,ij->i", a, lines)) / np.linalg.norm(lines[:, :2], axis=1)
        out: FloatArray = d * self.left.fx
        return out


def _normalized(cam: PinholeCamera, px: FloatArray) -> FloatArray:
    """Homogeneous normalized image coordinates (N, 3) of distorted pixels."""
    u = cam.undistort_pixels(px)
    x = (u[:, 0] - cam.K[0, 2]) / cam.K[0, 0]
    y = (u[:, 1] - cam.K[1, 2]) / cam.K[1, 1]
    return np.column_stack([x, y, np.ones(len(u))])


@dataclass(frozen=True, slots=True, kw_only=True)
class StereoMatches:
    """Left-to-right KLT matches: ``index`` into the left points, their pixels in both images,
    and how many were lost by KLT (with the border), the forward-backward check and the
    geometric check (the row for a rectified pair, the epipolar line for a calibrated one)."""

    index: IntArray
    left_px: FloatArray
    right_px: FloatArray
    lost_klt: int
    lost_fb: int
    lost_geometry: int

    def __len__(self) -> int:
        return int(self.index.size)


def track_stereo(
    left: object,
    right: object,
    *,
    config: TrackerConfig | None = None,
    left_px: FloatArray | None = None,
    geometry: StereoGeometry | None = None,
    max_error_px: float = 1.0,
) -> StereoMatches:
    """Match ``left_px`` (default: fresh corners of the left image) into the right image by KLT
    and back. Without ``geometry`` the pair is taken as rectified: a match must lie on the same
    row within ``max_error_px`` at a disparity >= 0; with it, within ``max_error_px`` of its
    epipolar line."""
    cfg = config or TrackerConfig()
    a, b = as_grey(left, "left image"), as_grey(right, "right image")
    if cfg.equalize:  # also evens out the two cameras' gains, which KLT does not model
        clahe = _clahe()
        a, b = np.asarray(clahe.apply(a), np.uint8), np.asarray(clahe.apply(b), np.uint8)
    if a.shape != b.shape:
        raise VisionError(f"stereo images differ in size: {a.shape[::-1]} and {b.shape[::-1]}")
    if not math.isfinite(max_error_px) or max_error_px <= 0:
        raise VisionError(f"max_error_px must be > 0, got {max_error_px}")
    shape = (a.shape[0], a.shape[1])
    pts = _detect(a, np.zeros((0, 2)), cfg.max_features, cfg) if left_px is None else left_px
    pts = np.asarray(pts, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or not np.isfinite(pts).all():
        raise VisionError(f"left_px must be finite (N, 2) pixels, got shape {pts.shape}")
    n = len(pts)
    s = _Survivors(pts, pts, np.arange(n, dtype=np.int64), np.zeros(n, np.int64))
    if len(pts):
        guess = None if geometry is None else geometry.at_infinity(pts)
        cur, ok = _klt(a, b, pts, cfg, guess=guess)
        s.cur = cur
        s.keep(ok & _in_border(cur, shape), "klt")
    if len(s.cur):
        back, ok_b = _klt(b, a, s.cur, cfg, guess=s.prev, levels=cfg.fb_pyramid_levels)
        s.keep(ok_b & (np.linalg.norm(back - s.prev, axis=1) <= cfg.fb_threshold_px), "fb")
    if len(s.cur) and geometry is None:
        row = np.abs(s.cur[:, 1] - s.prev[:, 1]) <= max_error_px
        s.keep(row & (s.prev[:, 0] - s.cur[:, 0] >= -max_error_px), "geometry")
    elif len(s.cur) and geometry is not None:
        s.keep(geometry.epipolar_error_px(s.prev, s.cur) <= max_error_px, "geometry")
    return StereoMatches(
        index=s.ids,
        left_px=s.prev,
        right_px=s.cur,
        lost_klt=s.losses.get("klt", 0),
        lost_fb=s.losses.get("fb", 0),
        lost_geometry=s.losses.get("geometry", 0),
    )
