"""Feature tracks and image statistics of a dataset's camera: how hard its images are to track.

The same tracker (GFTT + pyramidal KLT, VINS-Mono's front end) runs on any dataset, real or
made by ``quadnav dataset make``, so the synthetic worlds can be set beside real images: median
track length, the fraction of features tracked frame to frame, corners per frame, and the
images' brightness, contrast and gradient energy.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import asdict, dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import ConfigError
from quadnav.io.datasets import VisualInertialDataset
from quadnav.messages import ImageFrame
from quadnav.units import NS_PER_S, s_to_ns
from quadnav.vision.tracking import TrackerConfig, TrackStats, track_sequence

__all__ = ["ImageStats", "TrackStudy", "image_stats", "track_dataset"]

U8 = NDArray[np.uint8]


@dataclass(frozen=True, slots=True, kw_only=True)
class ImageStats:
    """Medians over the frames: mean grey level, contrast (standard deviation of the grey
    levels), mean gradient magnitude (Sobel, grey levels per pixel) and the corners GFTT finds
    at quality 0.01 with 10 px spacing (up to 1000)."""

    frames: int
    mean_grey: float
    contrast: float
    gradient: float
    corners: float


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackStudy:
    """A camera's tracks over a span of a dataset."""

    dataset: str
    camera: str
    start_s: float
    duration_s: float
    tracks: TrackStats
    images: ImageStats

    def to_json(self) -> dict[str, object]:
        out = asdict(self)
        out["tracks"] = self.tracks.to_json()
        return out


def _grey(img: U8) -> U8:
    if img.ndim == 3:
        return np.asarray(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), np.uint8)
    return img


class _ImageStatsAccumulator:
    def __init__(self) -> None:
        self.rows: list[tuple[float, float, float, float]] = []

    def add(self, img: U8) -> None:
        g = _grey(img)
        gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
        gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
        corners = cv2.goodFeaturesToTrack(g, 1000, 0.01, 10)
        n = 0 if corners is None else len(corners)
        self.rows.append((float(g.mean()), float(g.std()), float(np.hypot(gx, gy).mean()), n))

    def result(self) -> ImageStats:
        a = np.array(self.rows, dtype=np.float64).reshape(-1, 4)
        med = np.median(a, axis=0) if len(a) else np.full(4, np.nan)
        return ImageStats(
            frames=len(a),
            mean_grey=float(med[0]),
            contrast=float(med[1]),
            gradient=float(med[2]),
            corners=float(med[3]),
        )


def image_stats(images: Iterator[U8]) -> ImageStats:
    """:class:`ImageStats` of a sequence of images (consumed one at a time)."""
    acc = _ImageStatsAccumulator()
    for img in images:
        acc.add(img)
    return acc.result()


def _frames(
    ds: VisualInertialDataset, camera: str, start_s: float, duration_s: float | None
) -> list[ImageFrame]:
    frames = ds.frames_of(camera)
    if not frames:
        names = ", ".join(sorted({f.camera for f in ds.frames})) or "none"
        raise ConfigError(f"--camera {camera}: the dataset has no such camera (it has {names})")
    t0 = frames[0].t_ns + s_to_ns(start_s)
    t1 = t0 + s_to_ns(duration_s) if duration_s is not None else frames[-1].t_ns
    chosen = [f for f in frames if t0 <= f.t_ns <= t1]
    if len(chosen) < 2:
        raise ConfigError(
            f"--start {start_s:g} --duration {duration_s}: fewer than 2 frames of {camera} in that span"
        )
    return chosen


def track_dataset(
    ds: VisualInertialDataset,
    *,
    camera: str = "cam0",
    start_s: float = 0.0,
    duration_s: float | None = None,
    config: TrackerConfig | None = None,
) -> TrackStudy:
    """Track ``camera``'s frames from ``start_s`` for ``duration_s`` (to the end when None),
    undistorting with the dataset's own calibration; images are read one at a time."""
    frames = _frames(ds, camera, start_s, duration_s)
    lens = ds.rig.camera(camera).camera
    acc = _ImageStatsAccumulator()

    def images() -> Iterator[tuple[int, U8]]:
        for f in frames:
            img = _grey(f.image())
            acc.add(img)
            yield f.t_ns, img

    tracks = track_sequence(images(), config, lens)
    return TrackStudy(
        dataset=ds.name,
        camera=camera,
        start_s=start_s,
        duration_s=(frames[-1].t_ns - frames[0].t_ns) / NS_PER_S,
        tracks=tracks,
        images=acc.result(),
    )
