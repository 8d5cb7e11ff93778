"""The SLAM's map on disk (``quadnav slam --save-map DIR`` / ``--load-map DIR``; thesis 002
section 5.5: map, save, reload, relocalize): a folder (:mod:`quadnav.io.map_folder`) of
``map.json`` and ``slam_map.npz``, format ``quadnav-slam-map`` version 1, whose contents
:mod:`quadnav.slam.map` lists. A missing, truncated, corrupt or foreign map, one of another
version, or one whose arrays do not fit together, is a one-line :class:`~quadnav.errors.SlamError`
naming the option and folder; one made with another camera is refused when the SLAM is built
on it (:class:`~quadnav.slam.SlamOdometry`)."""

from __future__ import annotations

from pathlib import Path

from quadnav.errors import SlamError
from quadnav.io.map_folder import read_map_folder, write_map_folder
from quadnav.slam.frame import StereoCamera
from quadnav.slam.map import SLAM_MAP_FORMAT, SLAM_MAP_VERSION, SlamMap

__all__ = ["load_slam_map", "save_slam_map"]

_ARRAYS = "slam_map.npz"


def save_slam_map(
    folder: Path, slam_map: SlamMap, camera: StereoCamera, *, option: str = "--save-map"
) -> Path:
    """Write the map (measured in the rectified ``camera``) to ``folder``."""
    try:
        head, arrays = slam_map.to_arrays(camera)
    except SlamError as exc:
        raise SlamError(f"{option} {folder}: {exc}") from None
    return write_map_folder(folder, head, arrays, archive=_ARRAYS, error=SlamError, option=option)


def load_slam_map(folder: Path, *, option: str = "--load-map") -> tuple[SlamMap, StereoCamera]:
    """The map in ``folder`` and the rectified camera it was made with."""
    head, arrays = read_map_folder(folder, fmt=SLAM_MAP_FORMAT, version=SLAM_MAP_VERSION,
                                   archive=_ARRAYS, error=SlamError, option=option)  # fmt: skip
    try:
        return SlamMap.from_arrays(head, arrays)
    except SlamError as exc:
        raise SlamError(f"{option} {folder}: {exc}") from None
    except (KeyError, TypeError) as exc:
        raise SlamError(f"{option} {folder}: map.json lacks the camera ({exc})") from None
