"""The front end (thesis 003 §3.1.1): VINS-Mono's KLT tracker, each frame's features in
undistorted normalised coordinates with their image velocity, the keyframe decision of VINS'
``addFeatureCheckParallax`` (mean parallax of the features common with the last keyframe, or
too few of them tracked) and a feature manager keeping each track's keyframe observations.

Parallax may be compensated for the rotation between the two frames (the gyro's): a pure
rotation then makes no keyframe, only a translation does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.geometry.camera import PinholeCamera
from quadnav.odometry import FrameFeatures
from quadnav.vio.config import VioConfig
from quadnav.vision.tracking import FeatureTracker, TrackedFrame

__all__ = [
    "FeatureManager",
    "Frontend",
    "KeyframeDecision",
    "mean_parallax",
    "median_motion_px",
    "normalised",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def normalised(camera: PinholeCamera, undistorted_px: FloatArray) -> FloatArray:
    """Normalised image coordinates (z = 1) of undistorted pixels."""
    K = camera.K
    out = np.empty_like(undistorted_px, dtype=np.float64)
    out[:, 1] = (undistorted_px[:, 1] - K[1, 2]) / K[1, 1]
    out[:, 0] = (undistorted_px[:, 0] - K[0, 2] - K[0, 1] * out[:, 1]) / K[0, 0]
    return out


def _common(ids_a: IntArray, ids_b: IntArray) -> tuple[IntArray, IntArray]:
    """Indices into ``a`` and ``b`` of the ids both hold."""
    _, ia, ib = np.intersect1d(ids_a, ids_b, assume_unique=True, return_indices=True)
    return ia.astype(np.int64), ib.astype(np.int64)


def mean_parallax(
    ids_ref: IntArray,
    xy_ref: FloatArray,
    ids: IntArray,
    xy: FloatArray,
    R_ref_cur: FloatArray | None = None,
) -> tuple[float, int]:
    """Mean distance (normalised units) between the common features of a reference frame and
    this one, the current bearings first rotated into the reference camera by ``R_ref_cur``
    when given; and how many are common."""
    ia, ib = _common(ids_ref, ids)
    if ia.size == 0:
        return 0.0, 0
    cur = xy[ib]
    if R_ref_cur is not None:
        f = np.column_stack([cur, np.ones(len(cur))]) @ np.asarray(R_ref_cur).T
        ok = f[:, 2] > 1e-6
        cur = np.where(ok[:, None], f[:, :2] / np.maximum(f[:, 2:3], 1e-6), cur)
    d = np.linalg.norm(cur - xy_ref[ia], axis=1)
    return float(d.mean()), int(ia.size)


def median_motion_px(ref: FrameFeatures, frame: FrameFeatures) -> tuple[float, int]:
    """The median pixel displacement of the features common to two frames, and their count."""
    ia, ib = _common(ref.ids, frame.ids)
    if ia.size == 0:
        return float("inf"), 0
    return float(np.median(np.linalg.norm(frame.uv_px[ib] - ref.uv_px[ia], axis=1))), int(ia.size)


@dataclass(frozen=True, slots=True)
class KeyframeDecision:
    """A keyframe or not; ``by_time``: one only because ``keyframe_max_interval_s`` passed
    (little parallax, enough tracks)."""

    keyframe: bool
    parallax_px: float
    common: int
    by_time: bool = False


class Frontend:
    """Tracks a camera's images into :class:`FrameFeatures` and decides keyframes."""

    def __init__(self, camera: PinholeCamera, config: VioConfig) -> None:
        self.camera = camera
        self.config = config
        self.tracker = FeatureTracker(config.tracker, camera)
        self._prev: FrameFeatures | None = None
        self._kf: FrameFeatures | None = None

    def reset(self) -> None:
        self.tracker.reset()
        self._prev = None
        self._kf = None

    @property
    def last_keyframe(self) -> FrameFeatures | None:
        return self._kf

    @property
    def last_t_ns(self) -> int | None:
        """The time of the last frame tracked (None after a reset)."""
        return None if self._prev is None else self._prev.t_ns

    def track(
        self, t_ns: int, image: object, R_prev_cur: FloatArray | None = None
    ) -> FrameFeatures:
        """The features of an image (a :class:`VisionError` for one the tracker cannot use);
        ``R_prev_cur``: the camera's rotation since the last frame, KLT's prediction."""
        tf: TrackedFrame = self.tracker.track(t_ns, image, R_prev_cur=R_prev_cur)
        xy = normalised(self.camera, tf.pixels_undistorted)
        vel = np.zeros_like(xy)
        prev = self._prev
        if prev is not None and len(prev.ids) and len(tf.ids):
            ia, ib = _common(prev.ids, tf.ids)
            dt = (t_ns - prev.t_ns) * 1e-9
            vel[ib] = (xy[ib] - prev.xy[ia]) / dt
        frame = FrameFeatures(
            t_ns=int(t_ns),
            ids=np.asarray(tf.ids, np.int64),
            uv_px=np.asarray(tf.pixels, np.float64),
            xy=xy,
            velocity_xy_s=vel,
        )
        self._prev = frame
        return frame

    def decide(self, frame: FrameFeatures, R_kf_cur: FloatArray | None = None) -> KeyframeDecision:
        """VINS' keyframe test against the last keyframe (the first frame is one)."""
        cfg = self.config
        kf = self._kf
        if kf is None:
            return KeyframeDecision(True, 0.0, 0)
        par, n = mean_parallax(kf.ids, kf.xy, frame.ids, frame.xy, R_kf_cur)
        par_px = par * cfg.parallax_focal_px
        dt_s = (frame.t_ns - kf.t_ns) * 1e-9
        seen = n < cfg.keyframe_min_tracked or par_px >= cfg.keyframe_parallax_px
        by_time = not seen and dt_s >= cfg.keyframe_max_interval_s
        return KeyframeDecision(seen or by_time, par_px, n, by_time)

    def mark_keyframe(self, frame: FrameFeatures) -> None:
        self._kf = frame


class FeatureManager:
    """Each track's observations (normalised coordinates) in the window's keyframes, and with a
    stereo rig its observations in the second camera (``right``, by track and keyframe)."""

    def __init__(self) -> None:
        self.tracks: dict[int, dict[int, FloatArray]] = {}
        self.right: dict[int, dict[int, FloatArray]] = {}

    def clear(self) -> None:
        self.tracks.clear()
        self.right.clear()

    def add(self, kf: int, frame: FrameFeatures) -> None:
        for j, xy in zip(frame.ids.tolist(), frame.xy, strict=True):
            self.tracks.setdefault(int(j), {})[kf] = xy
        for j, xy in zip(frame.stereo_ids.tolist(), frame.stereo_xy, strict=True):
            self.right.setdefault(int(j), {})[kf] = xy

    def drop_keyframe(self, kf: int) -> None:
        for book in (self.tracks, self.right):
            for obs in book.values():
                obs.pop(kf, None)
            for j in [j for j, obs in book.items() if not obs]:
                del book[j]

    def observations(self, track: int) -> dict[int, FloatArray]:
        return self.tracks.get(track, {})
