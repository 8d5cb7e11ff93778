"""Image sources (a folder of images, a video file, a camera index) and the overlay video.

A frame that cannot be decoded, or whose size differs from the first frame's, is yielded as
``image=None`` with the reason, so a long video with a corrupt frame is processed to its end,
the frame skipped and counted. A source with no decodable frame at all is an error.

Time: a video container's timestamps; for an image folder or a raw elementary stream
(``.h264``, ``.mjpeg``: no timestamps, OpenCV would guess 25 fps) the configured frame rate;
for a live camera the arrival time of each frame (monotonic clock).
"""

from __future__ import annotations

import itertools
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.errors import IoError
from quadnav.units import s_to_ns

__all__ = [
    "CaptureProperty",
    "CaptureRequest",
    "Frame",
    "FrameSource",
    "FrameWindow",
    "ImagesOut",
    "VideoOut",
    "apply_capture_request",
    "cannot_write",
    "display_missing",
    "is_raw_stream",
    "open_frames",
    "quiet_libraries",
    "write_png",
]

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"}

TimeBase = Literal["timestamps", "fps", "clock"]


@dataclass(frozen=True, slots=True)
class Frame:
    index: int
    t_ns: int
    image: NDArray[np.uint8] | None
    error: str = ""


@dataclass(frozen=True, slots=True, kw_only=True)
class CaptureRequest:
    """What to ask of a live camera (thesis 000's ``fps``, ``frame_width``, ``frame_height``,
    ``exposure_time``); None leaves the driver's setting. ``exposure_time_100us`` is in V4L2's
    unit (100 us); 0 asks for automatic exposure."""

    fps: float | None = None
    frame_width_px: int | None = None
    frame_height_px: int | None = None
    exposure_time_100us: int | None = None


@dataclass(frozen=True, slots=True, kw_only=True)
class CaptureProperty:
    """One capture property: the value asked for, the value the driver reports after, and
    whether it took it."""

    name: str
    requested: float
    got: float
    accepted: bool


class FrameSource:
    """Iterate :class:`Frame` s; ``total`` is the frame count when known (None for a camera),
    ``size`` the (width, height) in px of its first decodable frame, ``time_base`` what the frame
    times come from, ``properties`` what a camera was asked and gave."""

    def __init__(
        self,
        kind: str,
        description: str,
        total: int | None,
        fps: float,
        it: Iterator[Frame],
        *,
        size: tuple[int, int] | None = None,
        time_base: TimeBase = "fps",
        properties: tuple[CaptureProperty, ...] = (),
    ) -> None:
        self.kind, self.description, self.total, self.fps = kind, description, total, fps
        self.size, self.time_base, self.properties = size, time_base, properties
        self._it = it

    def __iter__(self) -> Iterator[Frame]:
        return self._it


def _start(
    kind: str,
    description: str,
    total: int | None,
    fps: float,
    frames: Iterator[Frame],
    nothing: str,
    **kw: Any,
) -> FrameSource:
    """Read up to the first decodable frame (its size is the source's; none is an error that
    says ``nothing``), then hand out every frame from the start."""
    head: list[Frame] = []
    for fr in frames:
        head.append(fr)
        if fr.image is not None:
            size = (fr.image.shape[1], fr.image.shape[0])
            it = _same_size(itertools.chain(head, frames))
            return FrameSource(kind, description, total, fps, it, size=size, **kw)
    raise IoError(f"{description}: {nothing}")


def _same_size(frames: Iterator[Frame]) -> Iterator[Frame]:
    """Frames whose size differs from the first decoded one's become skipped frames."""
    size: tuple[int, int] | None = None
    for fr in frames:
        if fr.image is not None:
            h, w = fr.image.shape[:2]
            if size is None:
                size = (w, h)
            elif size != (w, h):
                why = f"size {w}x{h} differs from the first frame's {size[0]}x{size[1]}"
                fr = Frame(fr.index, fr.t_ns, None, why)
        yield fr


def _read_image(path: Path) -> NDArray[np.uint8] | None:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return None if img is None or img.size == 0 else np.asarray(img, np.uint8)


def _folder(path: Path, fps: float) -> FrameSource:
    files = (
        [path]
        if path.is_file()
        else sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    )
    if not files:
        raise IoError(f"{path}: no images ({', '.join(sorted(IMAGE_SUFFIXES))}) in this folder")
    period_ns = s_to_ns(1 / fps)

    def gen() -> Iterator[Frame]:
        for k, f in enumerate(files):
            img = _read_image(f)
            if img is None:
                yield Frame(k, k * period_ns, None, f"{f.name}: cannot be decoded")
            else:
                yield Frame(k, k * period_ns, img)

    what = (
        "cannot be decoded" if path.is_file() else f"none of the {len(files)} images can be decoded"
    )
    return _start("images", str(path), len(files), fps, gen(), what)


def is_raw_stream(path: Path) -> bool:
    """A raw elementary stream, which has no timestamps: H.264/H.265/MPEG-4 video in Annex B
    (starts with a start code, not an MPEG program stream's pack header) or raw MJPEG (starts
    with a JPEG)."""
    try:
        with path.open("rb") as f:
            head = f.read(5)
    except OSError:
        return False
    if head[:2] == b"\xff\xd8":
        return True
    code = 4 if head[:4] == b"\x00\x00\x00\x01" else 3 if head[:3] == b"\x00\x00\x01" else 0
    return code > 0 and head[code : code + 1] != b"\xba"


def _capture(
    cap: Any,
    kind: str,
    description: str,
    fps: float,
    time_base: TimeBase,
    properties: tuple[CaptureProperty, ...] = (),
) -> FrameSource:
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    # a raw stream's frame count is a guess from a guessed rate
    total = n if n > 0 and kind == "video" and time_base == "timestamps" else None

    def gen() -> Iterator[Frame]:
        k = 0
        misses = 0
        t0 = time.monotonic_ns()
        try:
            while True:
                ok, img = cap.read()
                t_arrival = time.monotonic_ns() - t0
                if not ok or img is None:
                    # A video may hold an undecodable frame before its end: skip it and go on
                    # while frames remain; a camera that stops delivering ends the stream.
                    if total is not None and k < total and misses < 5:
                        misses += 1
                        yield Frame(k, s_to_ns(k / fps), None, "frame cannot be decoded")
                        k += 1
                        continue
                    return
                misses = 0
                t_ms = float(cap.get(cv2.CAP_PROP_POS_MSEC))
                t_ns = (
                    round(t_ms * 1e6)
                    if time_base == "timestamps" and t_ms > 0
                    else t_arrival
                    if time_base == "clock"
                    else s_to_ns(k / fps)
                )
                yield Frame(k, t_ns, np.asarray(img, np.uint8))
                k += 1
        finally:
            cap.release()

    nothing = "no frame can be decoded" if kind == "video" else "gives no image"
    return _start(
        kind, description, total, fps, gen(), nothing, time_base=time_base, properties=properties
    )


def apply_capture_request(cap: Any, request: CaptureRequest) -> tuple[CaptureProperty, ...]:
    """Set what ``request`` asks on an OpenCV capture and read each property back."""
    wanted: list[tuple[str, int, float, float]] = []  # name, property, value, tolerance
    if request.frame_width_px is not None:
        wanted.append(("frame_width_px", cv2.CAP_PROP_FRAME_WIDTH, request.frame_width_px, 0.5))
    if request.frame_height_px is not None:
        wanted.append(("frame_height_px", cv2.CAP_PROP_FRAME_HEIGHT, request.frame_height_px, 0.5))
    if request.fps is not None:
        wanted.append(("fps", cv2.CAP_PROP_FPS, request.fps, 0.5))
    if request.exposure_time_100us is not None:
        # V4L2's exposure_auto: 1 manual, 3 automatic (aperture priority)
        manual = request.exposure_time_100us > 0
        wanted.append(("auto_exposure", cv2.CAP_PROP_AUTO_EXPOSURE, 1.0 if manual else 3.0, 0.01))
        if manual:
            wanted.append(
                ("exposure_time_100us", cv2.CAP_PROP_EXPOSURE, request.exposure_time_100us, 0.5)
            )
    out = []
    for name, prop, value, tol in wanted:
        ok = bool(cap.set(prop, float(value)))
        got = float(cap.get(prop))
        out.append(
            CaptureProperty(
                name=name, requested=float(value), got=got, accepted=ok and abs(got - value) <= tol
            )
        )
    return tuple(out)


def open_frames(
    source: str | Path,
    *,
    fps: float = 30.0,
    request: CaptureRequest | None = None,
    open_camera: Callable[[int], Any] = cv2.VideoCapture,
) -> FrameSource:
    """A folder of images or a raw stream (timed at ``fps``), a video file, or a camera index
    (``0``: opened by ``open_camera``, then asked for ``request``)."""
    s = str(source)
    if s.isdigit():
        cap = open_camera(int(s))
        if not cap.isOpened():
            raise IoError(f"camera {s} cannot be opened")
        props = apply_capture_request(cap, request) if request is not None else ()
        got_fps = float(cap.get(cv2.CAP_PROP_FPS)) or fps
        return _capture(cap, "camera", f"camera {s}", got_fps, "clock", props)
    path = Path(s)
    if path.is_dir() or (path.is_file() and path.suffix.lower() in IMAGE_SUFFIXES):
        return _folder(path, fps)
    if not path.exists():
        raise IoError(f"{path}: no such file or folder")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise IoError(f"{path}: not a video OpenCV can read")
    if is_raw_stream(path):
        return _capture(cap, "video", str(path), fps, "fps")
    return _capture(cap, "video", str(path), float(cap.get(cv2.CAP_PROP_FPS)) or fps, "timestamps")


@contextmanager
def quiet_libraries() -> Iterator[None]:
    """OpenCV's and FFmpeg's log lines off the terminal: quadnav counts and reports a
    skipped frame itself, and raises its own one-line error where OpenCV fails."""
    # read once, when OpenCV's FFmpeg backend starts: -8 is AV_LOG_QUIET
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(level)


class VideoOut:
    """An MP4 (``mp4v``) writer that opens on the first frame. OpenCV's FFmpeg writer tells no
    caller that the disk is full (it prints a warning per frame and goes on), so a frame is
    written only with room for it and a margin, or a one-line error naming the file."""

    #: Free space kept beyond a raw frame's size (FFmpeg buffers, the index written at close).
    MARGIN_BYTES = 1 << 20

    def __init__(self, path: Path, fps: float) -> None:
        self.path, self.fps = path, fps
        self._w: Any = None
        self.frames = 0

    def _check_room(self, nbytes: int) -> None:
        try:
            free = shutil.disk_usage(self.path.parent).free
        except OSError:
            return  # the writer reports what it cannot open
        if free < nbytes + self.MARGIN_BYTES:
            raise IoError(
                f"cannot write {self.path}: no space left on device ({free:,} bytes free)"
            )

    def write(self, image: NDArray[np.uint8]) -> None:
        img = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        self._check_room(img.nbytes)
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


def cannot_write(exc: OSError, path: Path) -> IoError:
    """One line for a failed write: the file the system names (else ``path``) and why."""
    return IoError(f"cannot write {exc.filename or path}: {exc.strerror or exc}")


def write_png(path: Path, image: NDArray[np.uint8] | NDArray[np.uint16]) -> None:
    """``image`` as a PNG file: encoded in memory, written by Python (an :class:`IoError` naming
    the file on failure, and no message of libpng's on stderr)."""
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise IoError(f"cannot write {path}: the image cannot be encoded as PNG")
    try:
        path.write_bytes(data.tobytes())
    except OSError as exc:
        raise cannot_write(exc, path) from None


class ImagesOut:
    """Every frame as ``frame_<index>.png`` in a folder (the thesis's ``write_images``), up to
    ``max_bytes`` in all: a frame that would take the folder past it is not written (counted
    in ``refused``)."""

    def __init__(self, folder: Path, max_bytes: int | None = None) -> None:
        self.folder = folder
        self.max_bytes = max_bytes
        self.frames = 0
        self.bytes = 0
        self.refused = 0
        self._last_bytes = 0
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise IoError(f"cannot create {folder}: {exc.strerror}") from None

    @property
    def full(self) -> bool:
        """The next frame (about the size of the last) would take the folder past the cap."""
        return self.max_bytes is not None and self.bytes + self._last_bytes > self.max_bytes

    def write(self, index: int, image: NDArray[np.uint8]) -> bool:
        """Write the frame; False when the cap keeps it out."""
        if self.full:
            self.refused += 1
            return False
        path = self.folder / f"frame_{index:06d}.png"
        write_png(path, image)
        try:
            self._last_bytes = path.stat().st_size
        except OSError as exc:
            raise IoError(f"{path}: {exc.strerror}") from None
        self.bytes += self._last_bytes
        self.frames += 1
        return True


def display_missing() -> str:
    """Why no window can open here ('' when one can): no X11/Wayland display on Linux, or an
    OpenCV built without a GUI."""
    if sys.platform.startswith(("linux", "freebsd", "openbsd")) and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        return "no display (DISPLAY and WAYLAND_DISPLAY are not set)"
    gui = [ln for ln in cv2.getBuildInformation().splitlines() if ln.strip().startswith("GUI:")]
    if gui and gui[0].split(":", 1)[1].strip().upper() in ("NONE", "NO", ""):
        return "this OpenCV has no GUI (opencv-python-headless?)"
    return ""


class FrameWindow:
    """An OpenCV window showing each frame; ``show`` returns False once the user pressed
    ``q`` or Esc in it."""

    def __init__(self, title: str, option: str) -> None:
        why = display_missing()
        if why:
            raise IoError(f"{option} needs a window, but {why}")
        self.title = title
        self.frames = 0

    def show(self, image: NDArray[np.uint8]) -> bool:
        try:
            cv2.imshow(self.title, image)
            key = cv2.waitKey(1) & 0xFF
        except cv2.error as exc:
            raise IoError(f"cannot show a window: {str(exc).strip().splitlines()[-1]}") from None
        self.frames += 1
        return key not in (ord("q"), 27)

    def close(self) -> None:
        if self.frames:
            cv2.destroyWindow(self.title)
