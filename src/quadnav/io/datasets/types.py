"""The one dataset type every reader returns: a rig, the camera frames (lazy images), the IMU
samples, the ground truth when the format has one, and what was rejected on the way.

``stream()`` merges frames and IMU samples into one time-ordered iterator. The frames keep the
stamps their source gives (the camera's clock); ``stream(apply_time_offset=True)`` moves each
frame to the IMU's clock by its camera's ``time_offset_ns`` (``t_imu = t_cam + offset``) before
the merge. At equal stamps the IMU sample comes first, then the cameras in rig order.
"""

from __future__ import annotations

import dataclasses
import heapq
from collections.abc import Collection, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import GeometryError, SampleError
from quadnav.geometry.trajectory import Trajectory
from quadnav.messages import ImageFrame, ImuSample
from quadnav.rig import Rig
from quadnav.units import ns_to_s

if TYPE_CHECKING:  # depth.py reads its files through files.py, which imports this module
    from quadnav.io.datasets.depth import DepthFrame

__all__ = ["DatasetIssues", "GroundTruth", "ImuTable", "VisualInertialDataset"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: How many rejected samples an issue list names before it only counts.
MAX_NAMED = 5


def _rows3(a: FloatArray | None, n: int, what: str) -> FloatArray | None:
    if a is None:
        return None
    arr = np.asarray(a, dtype=np.float64)
    if arr.shape != (n, 3) or not np.isfinite(arr).all():
        raise GeometryError(f"{what} must be finite (N, 3) for N = {n}, got {arr.shape}")
    return arr


@dataclass(frozen=True, slots=True, eq=False)
class ImuTable(Sequence[ImuSample]):
    """The IMU samples of a dataset as three arrays (a 20-minute sequence is 240,000 rows, which
    as Python objects would weigh ~100 MB); indexing and iteration give :class:`ImuSample`."""

    t_ns: IntArray
    gyro_rad_s: FloatArray
    accel_m_s2: FloatArray

    def __post_init__(self) -> None:
        t = np.asarray(self.t_ns, dtype=np.int64).reshape(-1)
        object.__setattr__(self, "t_ns", t)
        for name in ("gyro_rad_s", "accel_m_s2"):
            a = np.asarray(getattr(self, name), dtype=np.float64).reshape(-1, 3)
            if len(a) != len(t):
                raise GeometryError(f"IMU {name} has {len(a)} rows for {len(t)} stamps")
            if not np.isfinite(a).all():
                raise GeometryError(f"IMU {name} has a non-finite value")
            object.__setattr__(self, name, a)

    @classmethod
    def empty(cls) -> ImuTable:
        return cls(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))

    @classmethod
    def of(cls, samples: Sequence[ImuSample]) -> ImuTable:
        if not samples:
            return cls.empty()
        return cls(
            np.array([s.t_ns for s in samples], dtype=np.int64),
            np.array([s.gyro_rad_s for s in samples]),
            np.array([s.accel_m_s2 for s in samples]),
        )

    def __len__(self) -> int:
        return len(self.t_ns)

    def __getitem__(self, k: int) -> ImuSample:  # type: ignore[override]
        """Sample ``k``, built without checking it again: the table was checked whole (shapes,
        finite values) when made, and per-sample checks were 3/4 of the time of a stream."""
        s = object.__new__(ImuSample)
        object.__setattr__(s, "t_ns", int(self.t_ns[k]))
        object.__setattr__(s, "gyro_rad_s", self.gyro_rad_s[k].copy())
        object.__setattr__(s, "accel_m_s2", self.accel_m_s2[k].copy())
        return s

    def __iter__(self) -> Iterator[ImuSample]:
        for k in range(len(self.t_ns)):
            yield self[k]


@dataclass(frozen=True, slots=True, eq=False)
class GroundTruth:
    """The pose of the body in the dataset's world (``trajectory``), and where the format has
    them the velocity in the world and the IMU biases (EuRoC's ``state_groundtruth_estimate0``).
    ``orientation_known`` is False for a position-only source (EuRoC's ``leica0``: the
    quaternions are then the identity)."""

    trajectory: Trajectory
    v_W_B_m_s: FloatArray | None = None
    gyro_bias_rad_s: FloatArray | None = None
    accel_bias_m_s2: FloatArray | None = None
    orientation_known: bool = True
    source: str = ""

    def __post_init__(self) -> None:
        n = len(self.trajectory.t_ns)
        object.__setattr__(self, "v_W_B_m_s", _rows3(self.v_W_B_m_s, n, "ground-truth velocity"))
        for name in ("gyro_bias_rad_s", "accel_bias_m_s2"):
            object.__setattr__(self, name, _rows3(getattr(self, name), n, f"ground-truth {name}"))

    def __len__(self) -> int:
        return len(self.trajectory.t_ns)


@dataclass(frozen=True, slots=True)
class DatasetIssues:
    """Per-sample damage a reader rejected instead of failing on: a count per kind (``IMU rows
    with a NaN``, ``missing images``...), the first few named with file and line, and which of
    them are a camera's (``camera_counts``; ``named_cameras`` gives each named one's camera, or
    ``""``), so that a run on one camera reports only that camera's."""

    counts: dict[str, int] = field(default_factory=dict)
    named: tuple[str, ...] = ()
    camera_counts: dict[str, dict[str, int]] = field(default_factory=dict)
    named_cameras: tuple[str, ...] = ()

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def __bool__(self) -> bool:
        return self.total > 0

    def summary(self) -> str:
        if not self:
            return "no rejected samples"
        kinds = ", ".join(f"{n} {k}" for k, n in sorted(self.counts.items()))
        return f"rejected {kinds}; first: {self.named[0]}" if self.named else f"rejected {kinds}"

    def for_cameras(self, cameras: Collection[str]) -> DatasetIssues:
        """These issues without those of the cameras not in ``cameras`` (the IMU's and the
        ground truth's stay)."""
        counts = dict(self.counts)
        for cam, kinds in self.camera_counts.items():
            if cam not in cameras:
                for kind, n in kinds.items():
                    counts[kind] -= n
        named = [
            (text, cam)
            for text, cam in zip(self.named, self.named_cameras, strict=True)
            if not cam or cam in cameras
        ]
        return DatasetIssues(
            counts={k: n for k, n in counts.items() if n > 0},
            named=tuple(t for t, _ in named),
            camera_counts={c: dict(k) for c, k in self.camera_counts.items() if c in cameras},
            named_cameras=tuple(c for _, c in named),
        )


class IssueLog:
    """A reader's running tally, frozen into :class:`DatasetIssues` at the end."""

    def __init__(self, start: DatasetIssues | None = None) -> None:
        self.counts: dict[str, int] = dict(start.counts) if start else {}
        self.named: list[str] = list(start.named) if start else []
        self.camera_counts: dict[str, dict[str, int]] = (
            {c: dict(k) for c, k in start.camera_counts.items()} if start else {}
        )
        self.named_cameras: list[str] = list(start.named_cameras) if start else []

    def reject(self, kind: str, where: str, *, camera: str = "") -> None:
        """Count one rejected sample of ``kind`` at ``where`` (a camera's when ``camera``)."""
        self.counts[kind] = self.counts.get(kind, 0) + 1
        if camera:
            per = self.camera_counts.setdefault(camera, {})
            per[kind] = per.get(kind, 0) + 1
        if len(self.named) < MAX_NAMED:
            self.named.append(f"{where}: {kind}")
            self.named_cameras.append(camera)

    def freeze(self) -> DatasetIssues:
        return DatasetIssues(
            counts=dict(self.counts), named=tuple(self.named),
            camera_counts={c: dict(k) for c, k in self.camera_counts.items()},
            named_cameras=tuple(self.named_cameras),
        )  # fmt: skip


@dataclass(frozen=True, slots=True, eq=False, repr=False)
class VisualInertialDataset:
    """A camera-IMU sequence: ``rig`` (the calibration the files give), ``frames`` (every
    camera's, time ordered, cameras in rig order at equal stamps; pixels load on demand),
    ``imu`` (empty when the rig has none), ``groundtruth`` (None when absent), ``issues``, and
    the ``depth`` images of an RGB-D rig (empty otherwise; not part of ``stream()``)."""

    name: str
    root: Path
    kind: str
    rig: Rig
    frames: tuple[ImageFrame, ...]
    imu: ImuTable
    groundtruth: GroundTruth | None = None
    issues: DatasetIssues = field(default_factory=DatasetIssues)
    depth: tuple[DepthFrame, ...] = ()

    def frames_of(self, camera: str) -> list[ImageFrame]:
        self.rig.camera(camera)  # a one-line error for an unknown name
        return [f for f in self.frames if f.camera == camera]

    @property
    def duration_s(self) -> float:
        """From the first to the last sample (frame or IMU), in seconds."""
        ends = [int(t) for t in self.imu.t_ns[[0, -1]]] if len(self.imu) else []
        ends += [self.frames[0].t_ns, self.frames[-1].t_ns] if self.frames else []
        return ns_to_s(max(ends) - min(ends)) if ends else 0.0

    def __repr__(self) -> str:
        gt = f", {len(self.groundtruth)} ground-truth poses" if self.groundtruth else ""
        return (
            f"VisualInertialDataset({self.kind} {self.name!r}: cameras {self.rig.camera_names}, "
            f"{len(self.frames)} frames, {len(self.imu)} IMU samples{gt}, {self.duration_s:.1f} s; "
            f"{self.issues.summary()})"
        )

    def verified(self) -> VisualInertialDataset:
        """This dataset without the frames whose pixels cannot be had (a corrupt file, an
        undecodable message), those rejected and counted in ``issues``. It decodes every image
        once (and keeps none): a pass to make before a long run rather than fail in it."""
        log = IssueLog(self.issues)
        kept = []
        for f in self.frames:
            try:
                f.image()
            except SampleError:
                where = f.origin or f"{f.camera} at {f.t_ns}"
                log.reject("unreadable images", where, camera=f.camera)
            else:
                kept.append(f)
        return dataclasses.replace(self, frames=tuple(kept), issues=log.freeze())

    def stream(self, *, apply_time_offset: bool = False) -> Iterator[ImageFrame | ImuSample]:
        """Frames and IMU samples in one time-ordered iterator (see the module docstring)."""
        frames: Sequence[ImageFrame] = self.frames
        if apply_time_offset:
            offsets = {c.name: c.time_offset_ns for c in self.rig.cameras}
            shifted = [
                dataclasses.replace(f, t_ns=f.t_ns + offsets.get(f.camera, 0)) for f in frames
            ]
            frames = sorted(shifted, key=lambda f: f.t_ns)  # stable: rig order kept
        imu_keyed = ((int(t), 0, k) for k, t in enumerate(self.imu.t_ns))
        frame_keyed = ((f.t_ns, 1, k) for k, f in enumerate(frames))
        for _, which, k in heapq.merge(imu_keyed, frame_keyed):
            yield self.imu[k] if which == 0 else frames[k]


def sort_frames(frames: list[ImageFrame], camera_order: Sequence[str]) -> tuple[ImageFrame, ...]:
    """Frames by stamp, then by the rig's camera order."""
    rank = {c: i for i, c in enumerate(camera_order)}
    return tuple(sorted(frames, key=lambda f: (f.t_ns, rank.get(f.camera, len(rank)))))


#: What :func:`order_faults` says of a row: kept, a repeat of the row before, out of order.
IN_ORDER, REPEATED, OUT_OF_ORDER = 0, 1, 2


def order_faults(t_ns: IntArray) -> NDArray[np.int8]:
    """Per row, whether it keeps the stamps strictly increasing: ``IN_ORDER``, ``REPEATED`` (its
    stamp is the last kept one's) or ``OUT_OF_ORDER`` (it goes back before the last kept
    row, or jumps ahead of the row after it while that one follows on). One bad row costs one
    row, a stamp far in the future included; rows before the first fault are not looked at."""
    t = np.asarray(t_ns, dtype=np.int64)
    faults = np.zeros(len(t), dtype=np.int8)
    bad = np.flatnonzero(np.diff(t) <= 0)
    if not len(bad):
        return faults
    first = int(bad[0])
    last = int(t[first - 1]) if first > 0 else None
    for k in range(first, len(t)):
        tk = int(t[k])
        if last is not None and tk <= last:
            faults[k] = REPEATED if tk == last else OUT_OF_ORDER
        elif k + 1 < len(t) and t[k + 1] < tk and (last is None or t[k + 1] > last):
            faults[k] = OUT_OF_ORDER
        else:
            last = tk
    return faults
