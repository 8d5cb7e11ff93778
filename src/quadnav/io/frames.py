"""Image sources (a folder of images, a video file, a camera index) and the overlay video.

A frame that cannot be decoded is yielded as ``image=None`` with the reason, so a long video
with a corrupt frame is processed to its end, the frame skipped and counted.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import IoError

__all__ = ["Frame", "FrameSource", "VideoOut", "open_frames"]

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"}


@dataclass(frozen=True, slots=True)
class Frame:
    index: int
    t_ns: int
    image: NDArray[np.uint8] | None
    error: str = ""


class FrameSource:
    """Iterate :class:`Frame` s; ``total`` is the frame count when known (None for a camera)."""

    def __init__(self, kind: str, description: str, total: int | None, fps: float, it: Iterator[Frame]) -> None:  # fmt: skip
        self.kind, self.description, self.total, self.fps = kind, description, total, fps
        self._it = it

    def __iter__(self) -> Iterator[Frame]:
        return self._it


def _folder(path: Path, fps: float) -> FrameSource:
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise IoError(f"{path}: no images ({', '.join(sorted(IMAGE_SUFFIXES))}) in this folder")
    period_ns = round(1e9 / fps)

    def gen() -> Iterator[Frame]:
        for k, f in enumerate(files):
            img = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
            if img is None or img.size == 0:
                yield Frame(k, k * period_ns, None, f"{f.name}: cannot be decoded")
            else:
                yield Frame(k, k * period_ns, np.asarray(img, np.uint8))

    return FrameSource("images", str(path), len(files), fps, gen())


def _capture(cap: Any, kind: str, description: str, fps_default: float) -> FrameSource:
    fps = float(cap.get(cv2.CAP_PROP_FPS)) or fps_default
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    total = n if n > 0 and kind == "video" else None

    def gen() -> Iterator[Frame]:
        k = 0
        misses = 0
        try:
            while True:
                ok, img = cap.read()
                if not ok:
                    # A video may hold an undecodable frame before its end: skip it and go on
                    # while frames remain; a camera that stops delivering ends the stream.
                    if total is not None and k < total and misses < 5:
                        misses += 1
                        yield Frame(k, round(k * 1e9 / fps), None, "frame cannot be decoded")
                        k += 1
                        continue
                    return
                misses = 0
                t_ms = float(cap.get(cv2.CAP_PROP_POS_MSEC))
                t_ns = round(t_ms * 1e6) if kind == "video" and t_ms > 0 else round(k * 1e9 / fps)
                yield Frame(k, t_ns, np.asarray(img, np.uint8))
                k += 1
        finally:
            cap.release()

    return FrameSource(kind, description, total, fps, gen())


def open_frames(source: str | Path, *, fps: float = 30.0) -> FrameSource:
    """A folder of images (timed at ``fps``), a video file, or a camera index (``0``)."""
    s = str(source)
    if s.isdigit():
        cap = cv2.VideoCapture(int(s))
        if not cap.isOpened():
            raise IoError(f"camera {s} cannot be opened")
        return _capture(cap, "camera", f"camera {s}", fps)
    path = Path(s)
    if path.is_dir():
        return _folder(path, fps)
    if not path.exists():
        raise IoError(f"{path}: no such file or folder")
    if path.suffix.lower() in IMAGE_SUFFIXES:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        frame = Frame(0, 0, None if img is None else np.asarray(img, np.uint8), "" if img is not None else f"{path.name}: cannot be decoded")  # fmt: skip
        return FrameSource("images", str(path), 1, fps, iter([frame]))
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise IoError(f"{path}: not a video OpenCV can read")
    return _capture(cap, "video", str(path), fps)


class VideoOut:
    """An MP4 (``mp4v``) writer that opens on the first frame."""

    def __init__(self, path: Path, fps: float) -> None:
        self.path, self.fps = path, fps
        self._w: Any = None
        self.frames = 0

    def write(self, image: NDArray[np.uint8]) -> None:
        img = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        if self._w is None:
            h, w = img.shape[:2]
            self._w = cv2.VideoWriter(
                str(self.path), cv2.VideoWriter.fourcc(*"mp4v"), self.fps, (w, h)
            )
            if not self._w.isOpened():
                raise IoError(f"{self.path}: cannot write a video here")
        self._w.write(img)
        self.frames += 1

    def close(self) -> None:
        if self._w is not None:
            self._w.release()
