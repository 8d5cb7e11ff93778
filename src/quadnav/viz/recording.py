"""What every recording shares: the check that rerun is installed, the decimation that bounds a
stream, the timeline ``t`` (seconds, the files' stamps), columns sent and counted per entity,
trajectories as line strips and points, and the file written whole (``recording.rrd`` and
``recording.json``, which says what was kept of each stream: its rows and every how many)."""

from __future__ import annotations

import importlib.util
import math
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import VizError
from quadnav.io.run_folder import write_json

if TYPE_CHECKING:
    import rerun as rr
    import rerun.blueprint as rrb

__all__ = [
    "JPEG_QUALITY",
    "MAX_IMAGES",
    "MAX_IMAGE_WIDTH",
    "RECORDING_FILE",
    "RECORDING_JSON",
    "RecordingInfo",
    "RecordingLog",
    "decimation",
    "every_of",
    "eye_on",
    "finish_info",
    "flight_blueprint",
    "jpeg_of",
    "log_camera",
    "log_events",
    "log_images",
    "log_scalars",
    "log_trajectory",
    "log_vehicle",
    "open_recording",
    "require_rerun",
    "small_size",
    "streaming_to",
    "time_column",
    "with_note",
]

#: The recording's name in a run folder.
RECORDING_FILE = "recording.rrd"
#: Beside it: what was kept of each stream (rows, every how many), its size.
RECORDING_JSON = "recording.json"

#: Images kept of a camera: every n-th frame, n the smallest keeping at most this many.
MAX_IMAGES = 300
#: An image kept is downsampled by a whole factor to at most this width (pixels).
MAX_IMAGE_WIDTH = 320
#: The images' JPEG quality.
JPEG_QUALITY = 80

RGB = tuple[int, int, int]


@dataclass(frozen=True, slots=True, kw_only=True)
class RecordingInfo:
    """A recording written: its file, its size, the rows logged per entity over time (by
    rerun's entity path, ``/world/truth``) and every how many of its source's rows each keeps."""

    path: Path
    size_bytes: int
    rows: dict[str, int]
    every: dict[str, int] = field(default_factory=dict)
    #: where the recording was streamed too (a rerun URL), and what went wrong if it did
    streamed_to: str | None = None
    note: str = ""


def require_rerun(option: str) -> None:
    """Refuse ``option`` (``--rerun``, ``quadnav view``) when rerun is not installed."""
    if importlib.util.find_spec("rerun") is None:
        raise VizError(f"{option} needs rerun: pip install 'quadnav[viz]'")


def decimation(n: int, cap: int) -> NDArray[np.intp]:
    """The indices of every k-th of ``n`` rows, k the smallest keeping at most ``cap``."""
    step = max(1, math.ceil(n / max(cap, 1)))
    return np.arange(0, n, step)


def small_size(width: int, height: int, max_width: int) -> tuple[int, tuple[int, int]]:
    """The whole factor that brings ``width`` to at most ``max_width``, and the size it gives."""
    scale = max(1, math.ceil(width / max(max_width, 1)))
    return scale, (width // scale, height // scale)


def jpeg_of(image: NDArray[np.uint8], size: tuple[int, int]) -> bytes:
    """An image downsampled to ``size`` (width, height) and JPEG-encoded."""
    import cv2

    small = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    return buf.tobytes() if ok else b""


def time_column(t_ns: NDArray[np.int64]) -> rr.TimeColumn:
    """Stamps (ns) as the timeline ``t``."""
    import rerun as rr

    return rr.TimeColumn("t", duration=np.asarray(t_ns, dtype=np.int64).astype("timedelta64[ns]"))


class RecordingLog:
    """Columns sent to one recording, their rows counted per entity (and every how many of its
    source's rows they keep); stamps on the timeline from ``t0_ns``."""

    def __init__(self, rec: rr.RecordingStream, t0_ns: int = 0) -> None:
        self.rec = rec
        self.t0_ns = t0_ns
        self.rows: dict[str, int] = {}
        self.every: dict[str, int] = {}
        self.streamed_to: str | None = None
        self.note = ""

    def columns(
        self, entity: str, t_ns: NDArray[np.int64], columns: object, every: int = 1
    ) -> None:
        import rerun as rr

        if len(t_ns) == 0:
            return
        index = time_column(np.asarray(t_ns, np.int64) - self.t0_ns)
        rr.send_columns(entity, indexes=[index], columns=columns, recording=self.rec)  # type: ignore[arg-type]
        self.rows[f"/{entity}"] = self.rows.get(f"/{entity}", 0) + len(t_ns)
        self.every[f"/{entity}"] = every

    def at(self, t_ns: int) -> None:
        """The time of what is logged next with ``rec.log``."""
        self.rec.set_time("t", duration=np.timedelta64(int(t_ns) - self.t0_ns, "ns"))


def every_of(keep: NDArray[np.intp]) -> int:
    """Every how many rows ``keep`` (a :func:`decimation`) keeps."""
    return int(keep[1] - keep[0]) if len(keep) > 1 else 1


def log_trajectory(
    log: RecordingLog,
    name: str,
    t_ns: NDArray[np.int64],
    p: NDArray[np.float64],
    cap: int,
    colour: RGB,
    *,
    root: str = "world",
) -> None:
    """A trajectory whole as a static line strip (``ROOT/trajectories/NAME``) and its current
    point over time (``ROOT/NAME``), every k-th pose, at most ``cap``."""
    import rerun as rr

    keep = decimation(len(t_ns), cap)
    if len(keep) == 0:
        return
    strip = rr.LineStrips3D([p[keep]], colors=[colour], radii=[0.005])
    log.rec.log(f"{root}/trajectories/{name}", strip, static=True)
    points = rr.Points3D.columns(
        positions=p[keep], colors=[colour] * len(keep), radii=[0.02] * len(keep)
    )
    log.columns(f"{root}/{name}", t_ns[keep], points, every_of(keep))


#: The body axes' length drawn on the vehicle (m).
AXIS_LENGTH_M = 0.3


def log_vehicle(
    log: RecordingLog,
    t_ns: NDArray[np.int64],
    p: NDArray[np.float64],
    q_xyzw: NDArray[np.float64],
    cap: int,
    *,
    entity: str = "world/vehicle",
) -> None:
    """A pose over time with its axes (x red, y green, z blue), every k-th, at most ``cap``."""
    import rerun as rr

    keep = decimation(len(t_ns), cap)
    log.rec.log(entity, rr.TransformAxes3D(axis_length=AXIS_LENGTH_M), static=True)
    pose = rr.Transform3D.columns(translation=p[keep], quaternion=q_xyzw[keep])
    log.columns(entity, t_ns[keep], pose, every_of(keep))


def log_scalars(
    log: RecordingLog, entity: str, t_ns: NDArray[np.int64], values: NDArray[np.float64], cap: int
) -> None:
    """One time series, every k-th value, at most ``cap``."""
    import rerun as rr

    keep = decimation(len(t_ns), cap)
    log.columns(entity, t_ns[keep], rr.Scalars.columns(scalars=values[keep]), every_of(keep))


def log_camera(
    log: RecordingLog, entity: str, T_B_C: NDArray[np.float64], K: NDArray[np.float64],
    size: tuple[int, int], depth_m: float = 0.25,
) -> None:  # fmt: skip
    """A camera fixed on its parent entity at ``T_B_C`` (4x4), its frustum ``depth_m`` deep;
    ``K`` is ``(fx, fy, cx, cy)`` of images of ``size`` (width, height)."""
    import rerun as rr

    T = np.asarray(T_B_C, np.float64)
    log.rec.log(entity, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)
    fx, fy, cx, cy = (float(v) for v in K)
    pinhole = rr.Pinhole(
        focal_length=[fx, fy], principal_point=[cx, cy], width=size[0], height=size[1],
        camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=depth_m,
    )  # fmt: skip
    log.rec.log(entity, pinhole, static=True)


def log_images(
    log: RecordingLog, entity: str, t_ns: NDArray[np.int64], jpegs: Sequence[bytes], every: int
) -> None:
    """JPEG images over time (every ``every``-th of their source's)."""
    import rerun as rr

    images = rr.EncodedImage.columns(blob=list(jpegs), media_type=["image/jpeg"] * len(jpegs))
    log.columns(entity, np.asarray(t_ns, np.int64), images, every)


def log_events(
    log: RecordingLog, events: Sequence[tuple[int, str]], *, level: str = "WARN",
    entity: str = "events",
) -> None:  # fmt: skip
    """Events ``(t_ns, text)`` as a text log, each at its time."""
    import rerun as rr

    for t_ns, text in events:
        log.at(t_ns)
        log.rec.log(entity, rr.TextLog(text, level=level))
    log.rows[f"/{entity}"] = log.rows.get(f"/{entity}", 0) + len(events)


def eye_on(p: NDArray[np.float64]) -> rrb.EyeControls3D | None:
    """Looking down on the positions ``p`` from behind their start, all of them in view."""
    import rerun.blueprint as rrb

    if len(p) == 0 or not np.isfinite(p).all():
        return None
    lo, hi = p.min(axis=0), p.max(axis=0)
    centre, size = (lo + hi) / 2, max(float(np.max(hi - lo)), 1.0)
    return rrb.EyeControls3D(
        position=centre + size * np.array([-0.9, -1.4, 1.2]), look_target=centre,
        eye_up=[0.0, 0.0, 1.0],
    )  # fmt: skip


def flight_blueprint(
    title: str, positions: NDArray[np.float64] | None, series: Sequence[tuple[str, str]],
    *, side: Sequence[rrb.View] = (),
) -> rrb.Blueprint:  # fmt: skip
    """One 3-D view of ``/world`` (looking at ``positions``) beside the views ``side`` (three
    times the height of each other) above a time series per ``(name, origin)`` and the events;
    opened at the run's end."""
    import rerun.blueprint as rrb

    views = [rrb.TimeSeriesView(name=name, origin=origin) for name, origin in series]
    shares = [3.0] * len(side) + [1.0] * (len(views) + 1)  # (an image needs the room)
    events = rrb.TextLogView(name="events", origin="/events")
    column = rrb.Vertical(*side, *views, events, row_shares=shares)
    eye = eye_on(positions if positions is not None else np.zeros((0, 3)))
    world = rrb.Spatial3DView(name=title, origin="/world", eye_controls=eye)
    layout = rrb.Horizontal(world, column, column_shares=[3, 2])
    end = rrb.TimePanel(timeline="t", play_state="following", expanded=False)
    return rrb.Blueprint(layout, end, collapse_panels=True)


_STREAM_TO: ContextVar[str | None] = ContextVar("stream_to", default=None)


@contextmanager
def streaming_to(url: str | None) -> Iterator[None]:
    """The recordings opened in the block are streamed to ``url`` (a rerun gRPC URL) too."""
    token = _STREAM_TO.set(url)
    try:
        yield
    finally:
        _STREAM_TO.reset(token)


@contextmanager
def open_recording(
    path: Path, recording_id: str, blueprint: rrb.Blueprint, *, t0_ns: int = 0
) -> Iterator[RecordingLog]:
    """A recording to ``path`` (an ``.rrd``, replaced whole when the block ends without an
    error), its world ENU, z up, its timeline from ``t0_ns``."""
    import rerun as rr

    path = Path(path)
    partial = path.with_name(path.name + ".partial")
    rec = rr.RecordingStream("quadnav", recording_id=recording_id)
    log = RecordingLog(rec, t0_ns)
    log.streamed_to = _STREAM_TO.get()
    if log.streamed_to is None:
        rec.save(partial, default_blueprint=blueprint)
    else:  # the file and the viewer at once, the blueprint to both
        rec.set_sinks(rr.FileSink(partial), rr.GrpcSink(log.streamed_to))
        rec.send_blueprint(blueprint, make_active=True, make_default=True)
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    try:
        yield log
    finally:
        try:
            rec.flush()
        except RuntimeError as exc:  # the viewer went away: the file is still whole
            log.note = f"--rerun-connect {log.streamed_to}: {exc}".replace("\n", " ")
        rec.disconnect()
    partial.replace(path)


def finish_info(log: RecordingLog, path: Path) -> RecordingInfo:
    """The recording written, said in ``recording.json`` beside it."""
    path = Path(path)
    info = RecordingInfo(
        path=path, size_bytes=path.stat().st_size, rows=dict(log.rows), every=dict(log.every),
        streamed_to=log.streamed_to, note=log.note,
    )  # fmt: skip
    _write_info(info)
    return info


def with_note(info: RecordingInfo, note: str) -> RecordingInfo:
    """``info`` with ``note`` added (``recording.json`` rewritten)."""
    if not note:
        return info
    joined = f"{info.note}; {note}" if info.note else note
    out = RecordingInfo(path=info.path, size_bytes=info.size_bytes, rows=info.rows,
                        every=info.every, streamed_to=info.streamed_to, note=joined)  # fmt: skip
    _write_info(out)
    return out


def _write_info(info: RecordingInfo) -> None:
    path = info.path
    write_json(
        path.with_name(RECORDING_JSON)
        if path.name == RECORDING_FILE
        else path.with_suffix(".json"),
        {
            "file": path.name,
            "size_bytes": info.size_bytes,
            "rows": info.rows,
            "every": info.every,
            "streamed_to": info.streamed_to,
            "note": info.note,
        },
    )
