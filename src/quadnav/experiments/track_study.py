"""Feature tracks and image statistics of a dataset's camera: how hard its images are to track.

The same tracker (GFTT + pyramidal KLT, VINS-Mono's front end) runs on any dataset, real or
made by ``quadnav dataset make``, so the synthetic worlds can be set beside real images: median
track length, the fraction of features tracked frame to frame, corners per frame, and the
images' brightness, contrast and gradient energy.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import ConfigError
from quadnav.geometry.camera import PinholeCamera
from quadnav.io.datasets import VisualInertialDataset
from quadnav.messages import ImageFrame
from quadnav.units import NS_PER_S, s_to_ns
from quadnav.vision.tracking import TrackerConfig, TrackStats, as_grey, track_sequence

__all__ = [
    "ImageStats",
    "RotationRow",
    "TrackStudy",
    "crop_camera",
    "image_stats",
    "rotation_study",
    "sway",
    "track_dataset",
    "warped_views",
]

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


class _ImageStatsAccumulator:
    def __init__(self) -> None:
        self.rows: list[tuple[float, float, float, float]] = []

    def add(self, img: U8) -> None:
        g = as_grey(img)
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
            img = as_grey(f.image())
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


@dataclass(frozen=True, slots=True, kw_only=True)
class RotationRow:
    """Tracks of the same pure rotation (yaw and pitch swaying with a peak rate) seen in a real
    image (warped by the rotation's homography, exact for a pure rotation) and in a world."""

    peak_rate_deg_s: float
    frames: int
    real: TrackStats
    synthetic: TrackStats

    def to_json(self) -> dict[str, object]:
        return {
            "peak_rate_deg_s": self.peak_rate_deg_s,
            "frames": self.frames,
            "real": self.real.to_json(),
            "synthetic": self.synthetic.to_json(),
        }


def sway(
    peak_rate_deg_s: float, frames: int, rate_hz: float, amplitude_deg: float = 6.0
) -> list[Rotation]:
    """Rotations of a camera swaying in yaw (and half as much in pitch) with the given peak rate."""
    f_hz = peak_rate_deg_s / (amplitude_deg * 2.0 * np.pi)
    t = np.arange(frames) / rate_hz
    yaw = amplitude_deg * np.sin(2.0 * np.pi * f_hz * t)
    pitch = 0.5 * amplitude_deg * np.cos(2.0 * np.pi * f_hz * t * 0.7)
    # camera frame: yaw turns about its y (down) axis, pitch about its x (right) axis
    return [
        Rotation.from_euler("YX", [y, p], degrees=True) for y, p in zip(yaw, pitch, strict=True)
    ]


def crop_camera(K: NDArray[np.float64], width: int, height: int) -> PinholeCamera:
    """A pinhole camera of ``width`` x ``height`` with ``K``'s focal lengths, centred."""
    Kc = K.copy()
    Kc[0, 2], Kc[1, 2] = (width - 1) / 2.0, (height - 1) / 2.0
    return PinholeCamera(Kc, np.zeros(0), width, height)


def warped_views(
    image: U8, K_src: NDArray[np.float64], view: PinholeCamera, rotations: list[Rotation]
) -> Iterator[U8]:
    """``image`` (undistorted, camera ``K_src``) as cameras turned by ``rotations`` see it."""
    K_inv = np.linalg.inv(view.K)
    for R in rotations:
        H = K_src @ R.as_matrix() @ K_inv  # destination pixel -> source pixel
        yield np.asarray(
            cv2.warpPerspective(
                image, H, (view.width, view.height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
            ),
            np.uint8,
        )


def rotation_study(
    real: U8,
    real_camera: PinholeCamera,
    rendered: Callable[[Rotation], U8],
    view: PinholeCamera,
    rates_deg_s: tuple[float, ...] = (30.0, 60.0, 120.0),
    *,
    frames: int = 60,
    rate_hz: float = 20.0,
    seed: int = 0,
) -> list[RotationRow]:
    """For each peak rate, track the real image warped by the sway's rotations and the world
    rendered by ``rendered(R)`` under the same rotations, both with the same fresh sensor noise
    (2 grey levels) per frame."""
    from quadnav.sim.render import RenderEffects

    undistorted = np.asarray(
        cv2.undistort(as_grey(real), real_camera.K, real_camera.dist), np.uint8
    )
    noise = RenderEffects(read_noise_sigma=1.5, shot_noise_dn=0.03)
    rows = []
    for rate in rates_deg_s:
        rots = sway(rate, frames, rate_hz)
        rng_a, rng_b = np.random.default_rng(seed), np.random.default_rng(seed)
        real_seq = (
            (s_to_ns(k / rate_hz), noise.apply(img, rng_a))
            for k, img in enumerate(warped_views(undistorted, real_camera.K, view, rots))
        )
        syn_seq = (
            (s_to_ns(k / rate_hz), noise.apply(rendered(R), rng_b)) for k, R in enumerate(rots)
        )
        rows.append(
            RotationRow(
                peak_rate_deg_s=rate,
                frames=frames,
                real=track_sequence(real_seq),
                synthetic=track_sequence(syn_seq),
            )
        )
    return rows
