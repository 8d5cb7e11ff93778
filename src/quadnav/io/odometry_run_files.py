"""A visual odometry run folder read back (``quadnav vio`` and ``quadnav slam``'s files) for
whatever shows it again (``quadnav view``), and the one file a run adds for that: ``viz.npz``,
what its images showed (written with ``--rerun``).

``viz.npz`` holds what the other files do not: the camera's images, downsampled and every n-th
(JPEG, ``image_every`` and ``image_scale`` say which and how), the features tracked in them,
each state's tracked count and position covariance, the landmarks the keyframes saw (each once,
at the time it was first seen, at its last position), and the camera's intrinsics and extrinsic.
It is read without pickles. A folder that is no odometry run folder, or a malformed file, is a
one-line :class:`IoError` naming it.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import IoError
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.run_folder import checked_run_folder, read_json, read_jsonl
from quadnav.io.trajectory_io import read_tum

__all__ = [
    "ODOMETRY_REQUIRED",
    "VIZ_CAPTURE",
    "OdometryRunFiles",
    "VizCapture",
    "is_odometry_run_folder",
    "read_odometry_run",
    "read_viz_capture",
    "write_viz_capture",
]

#: The files without which a folder is no ``quadnav vio`` or ``quadnav slam`` folder.
ODOMETRY_REQUIRED = ("metrics.json", "estimate.tum", "keyframes.tum", "events.jsonl")
#: The run folder's file of what the images showed (``--rerun``).
VIZ_CAPTURE = "viz.npz"

IntArray = NDArray[np.int64]
FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class VizCapture:
    """What a run's camera showed, kept for its recording (see the module). Images: ``(I,)``
    stamps, JPEG bytes concatenated with ``I + 1`` offsets, ``width`` x ``height`` pixels (the
    camera's divided by ``image_scale``), every ``image_every``-th frame; ``K`` (fx, fy, cx, cy)
    in those pixels; ``T_B_C`` (4x4). Features ``(M,)``: the image each is in, its track id, its
    pixel ``(M, 2)`` in the small image and its track length. Frames ``(F,)``: the camera's
    stamps. States ``(S,)``: stamps, features tracked, position covariance in the world
    ``(S, 3, 3)``.
    Landmarks ``(L,)``: id, first seen, position ``(L, 3)``; ``landmarks_dropped`` those past
    the bound."""

    camera: str
    image_every: int
    image_scale: int
    width: int
    height: int
    K: FloatArray
    T_B_C: FloatArray
    image_t_ns: IntArray
    jpeg: NDArray[np.uint8]
    jpeg_offsets: IntArray
    feature_image: IntArray
    feature_ids: IntArray
    feature_uv: FloatArray
    feature_length: IntArray
    frame_t_ns: IntArray
    state_t_ns: IntArray
    state_tracked: IntArray
    state_cov_p_W: FloatArray
    landmark_ids: IntArray
    landmark_t_ns: IntArray
    landmark_W: FloatArray
    landmarks_dropped: int = 0

    def image_bytes(self, k: int) -> bytes:
        """The ``k``-th image, JPEG-encoded."""
        return self.jpeg[self.jpeg_offsets[k] : self.jpeg_offsets[k + 1]].tobytes()


_SCALARS = ("camera", "image_every", "image_scale", "width", "height", "landmarks_dropped")


def write_viz_capture(path: Path, capture: VizCapture) -> None:
    """Write ``capture`` to ``path`` (``viz.npz``), replaced whole."""
    path = Path(path)
    arrays = {f.name: np.asarray(getattr(capture, f.name)) for f in fields(VizCapture)}
    partial = path.with_name(path.name + ".partial.npz")
    np.savez_compressed(partial, **arrays)  # type: ignore[arg-type]
    partial.replace(path)


def read_viz_capture(path: Path) -> VizCapture:
    """``viz.npz`` read back (an error naming it when it is not one)."""
    try:
        with np.load(Path(path), allow_pickle=False) as z:
            values = {f.name: z[f.name] for f in fields(VizCapture)}
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        raise IoError(f"{path}: not a run's viz.npz ({exc})") from None
    for name in _SCALARS:
        values[name] = values[name].item()
    return VizCapture(**values)


@dataclass(frozen=True, slots=True, kw_only=True)
class OdometryRunFiles:
    """The series of a ``quadnav vio`` / ``quadnav slam`` folder: ``kind`` (``vio``, ``slam``),
    the estimate at each camera frame, the keyframes (as published; ``keyframes_loop`` as the
    last pose graph has them with ``--loop``, ``keyframes_final`` as a SLAM's map has them at
    the end), the ground truth, a SLAM's frames through its final map, the accepted loops
    (``(t_old_ns, t_new_ns)``), the events (``(t_ns, kind, detail)``) and ``viz.npz``."""

    run_dir: Path
    kind: str
    estimate: Trajectory
    keyframes: Trajectory
    truth: Trajectory | None = None
    keyframes_loop: Trajectory | None = None
    keyframes_final: Trajectory | None = None
    estimate_final: Trajectory | None = None
    loops: tuple[tuple[int, int], ...] = ()
    events: tuple[tuple[int, str, str], ...] = ()
    capture: VizCapture | None = None


def is_odometry_run_folder(run_dir: Path) -> bool:
    """True when ``run_dir`` holds a ``quadnav vio`` or ``quadnav slam`` folder's series."""
    run_dir = Path(run_dir)
    if not all((run_dir / name).is_file() for name in ODOMETRY_REQUIRED):
        return False
    try:
        return "camera" in read_json(run_dir / "metrics.json")
    except IoError:
        return False


def _optional_tum(path: Path) -> Trajectory | None:
    return read_tum(path) if path.is_file() else None


def _loops(path: Path) -> tuple[tuple[int, int], ...]:
    """The accepted loops of ``loop.json`` (old and new keyframes' stamps)."""
    if not path.is_file():
        return ()
    places = read_json(path).get("places", [])
    out = []
    for p in places if isinstance(places, list) else []:
        if isinstance(p, dict) and p.get("stage") == "accepted":
            out.append((int(p["t_old_ns"]), int(p["t_new_ns"])))
    return tuple(out)


def _events(path: Path) -> tuple[tuple[int, str, str], ...]:
    try:
        return tuple(
            (int(str(e["t_ns"])), str(e.get("kind", "")), str(e.get("detail", "")))
            for e in read_jsonl(path)
        )
    except (KeyError, ValueError) as exc:
        raise IoError(f"{path}: an event without its t_ns ({exc})") from None


def read_odometry_run(run_dir: Path, *, complete: bool = True) -> OdometryRunFiles:
    """The series of a ``quadnav vio`` / ``quadnav slam`` folder (an error naming it otherwise);
    ``complete``: refuse one not marked complete (the run building its own recording reads its
    folder before it is)."""
    run_dir = checked_run_folder(
        run_dir,
        "quadnav vio or slam",
        ODOMETRY_REQUIRED,
        is_odometry_run_folder,
        complete=complete,
        not_kind="not an odometry run's",
    )
    final = _optional_tum(run_dir / "keyframes_final.tum")
    capture = run_dir / VIZ_CAPTURE
    return OdometryRunFiles(
        run_dir=run_dir,
        kind="slam" if final is not None else "vio",
        estimate=read_tum(run_dir / "estimate.tum"),
        keyframes=read_tum(run_dir / "keyframes.tum"),
        truth=_optional_tum(run_dir / "groundtruth.tum"),
        keyframes_loop=_optional_tum(run_dir / "keyframes_loop.tum"),
        keyframes_final=final,
        estimate_final=_optional_tum(run_dir / "estimate_final.tum"),
        loops=_loops(run_dir / "loop.json"),
        events=_events(run_dir / "events.jsonl"),
        capture=read_viz_capture(capture) if capture.is_file() else None,
    )
