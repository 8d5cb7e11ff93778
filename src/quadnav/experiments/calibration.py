"""Camera calibration from the ChArUco views of a source (an image folder or a video): the work
behind ``quadnav calibrate``, which only parses its options and prints the result."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from quadnav.errors import ConfigError, VisionError
from quadnav.io.frames import open_frames
from quadnav.io.opencv_yaml import write_camera_yaml
from quadnav.vision.calibration import Calibration, calibrate_charuco
from quadnav.vision.markers import CharucoDetections, CharucoSpec, CharucoTarget

__all__ = ["SourceCalibration", "calibrate_source", "write_source_calibration"]

Progress = Callable[[int, int, str], None]


@dataclass(frozen=True, slots=True, kw_only=True)
class SourceCalibration:
    """A source's calibration (its views keyed by the source's frame numbers), the frames read
    from it and those that could not be decoded."""

    calibration: Calibration
    frames_read: int
    unreadable: tuple[str, ...]


def calibrate_source(
    source: str | Sequence[str],
    spec: CharucoSpec,
    *,
    every: int = 1,
    max_views: int = 60,
    progress: Progress | None = None,
) -> SourceCalibration:
    """Detect the board in every ``every``-th frame of ``source`` (a folder of images, a video,
    an image, or several of them, their frames numbered on from one to the next) and calibrate
    from the views with the most corners (at most ``max_views``); refused as
    :func:`calibrate_charuco` refuses, the source named."""
    sources = [source] if isinstance(source, str) else list(source)
    if not sources:
        raise ConfigError("no source: give a folder of images, a video or image files")
    name = sources[0] if len(sources) == 1 else f"{sources[0]} (and {len(sources) - 1} more)"
    target = CharucoTarget(spec)
    views, size, unreadable, n = _detect_views(sources, target, every, progress)
    if size is None:
        raise ConfigError(f"{name}: no readable image")
    views.sort(key=lambda v: -len(v[1].corner_ids))
    chosen = sorted(views[:max_views], key=lambda v: v[0])
    try:
        cal = calibrate_charuco([d for _, d in chosen], target, size)
    except VisionError as exc:
        raise VisionError(f"{name}: {exc}") from None
    frame = [index for index, _ in chosen]  # view k of the calibration is frame[k]
    cal = dataclasses.replace(
        cal,
        per_view_rms_px={frame[k]: e for k, e in cal.per_view_rms_px.items()},
        rejected={frame[k]: why for k, why in cal.rejected.items()},
    )
    return SourceCalibration(calibration=cal, frames_read=n, unreadable=tuple(unreadable))


def _detect_views(
    sources: list[str], target: CharucoTarget, every: int, progress: Progress | None
) -> tuple[list[tuple[int, CharucoDetections]], tuple[int, int] | None, list[str], int]:
    """The board's detections in every ``every``-th frame (numbered across the sources), the
    image size (the first readable frame's; frames of another size are set aside), the frames
    that could not be used and the number of frames read."""
    views: list[tuple[int, CharucoDetections]] = []
    size: tuple[int, int] | None = None
    unreadable: list[str] = []
    n = 0
    for source in sources:
        frames = open_frames(source)
        first = n
        for fr in frames:
            n += 1
            k = first + fr.index
            if k % every:
                continue
            if fr.image is None:
                unreadable.append(f"frame {k}: {fr.error}")
                continue
            shape = (fr.image.shape[1], fr.image.shape[0])
            size = size or shape
            if shape != size:
                other = f"{shape[0]}x{shape[1]}, not {size[0]}x{size[1]}"
                unreadable.append(f"frame {k} of {source}: {other}")
                continue
            views.append((k, target.detect(fr.image)))
            if progress is not None:
                progress(k + 1, first + (frames.total or 0), f"{len(views)} views")
    return views, size, unreadable, n


def write_source_calibration(path: Path, result: SourceCalibration) -> None:
    """The calibration as OpenCV YAML, with its RMS reprojection error and number of views."""
    cal = result.calibration
    write_camera_yaml(
        path, cal.camera, avg_reprojection_error=cal.rms_px, views=len(cal.per_view_rms_px)
    )
