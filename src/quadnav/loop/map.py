"""A map loop closure can save and load (VINS-Mono's ``pose_graph_save_path`` and
``load_previous_pose_graph``): its keyframes in the map's frame, each with its keypoints and
descriptors, the landmarks it sees, its bag of words and direct index, and the loops between
them; the camera and the vocabulary they were made with. Pure: :mod:`quadnav.io.loop_map`
puts it on disk (the format is documented there) and reads it back.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import LoopError, QuadnavError
from quadnav.geometry.rotations import Pose
from quadnav.odometry import KeyframeRecord
from quadnav.place.database import DirectIndex
from quadnav.place.vocabulary import BowVector
from quadnav.posegraph.types import LoopEdge
from quadnav.rig import CameraSpec

__all__ = ["MAP_FORMAT", "MAP_FRAME", "MAP_VERSION", "LoopMap", "MapCamera", "MapKeyframe"]

MAP_FORMAT = "quadnav-loop-map"
MAP_VERSION = 1
#: The odometry frame (pose graph frame) of a loaded map's keyframes: held where they are.
MAP_FRAME = -1

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class MapCamera:
    """The camera a map's keyframes were taken with: another camera's keypoints and
    descriptors do not match them."""

    name: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def of(cls, spec: CameraSpec) -> MapCamera:
        K = spec.camera.K
        return cls(name=spec.name, width=int(spec.camera.width), height=int(spec.camera.height),
                   fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]), cy=float(K[1, 2]))  # fmt: skip

    def mismatch(self, other: MapCamera) -> str | None:
        """Why ``other`` is not this camera (another image size, or focal length or centre more
        than 2 % apart), or None."""
        if (self.width, self.height) != (other.width, other.height):
            return f"images {other.width}x{other.height}, the map's {self.width}x{self.height}"
        for what, a, b in (("fx", self.fx, other.fx), ("fy", self.fy, other.fy),
                           ("cx", self.cx, other.cx), ("cy", self.cy, other.cy)):  # fmt: skip
            if abs(a - b) > 0.02 * max(abs(a), 1.0):
                return f"{what} {b:.1f} px, the map's {a:.1f} px"
        return None


@dataclass(frozen=True, slots=True, kw_only=True)
class MapKeyframe:
    """A keyframe of a map: its record in the map's frame (pose, landmarks; ``reset_counter``
    :data:`MAP_FRAME`, no image) and its place in the database (bag of words, direct index)."""

    record: KeyframeRecord
    bow: BowVector
    direct: DirectIndex


@dataclass(frozen=True, slots=True, kw_only=True)
class LoopMap:
    """Keyframes (indices increasing), the loops between them (``old``/``new`` are keyframe
    indices), the camera and the vocabulary's fingerprint."""

    keyframes: tuple[MapKeyframe, ...]
    loops: tuple[LoopEdge, ...]
    camera: MapCamera
    vocabulary: str

    def __post_init__(self) -> None:
        idx = [k.record.index for k in self.keyframes]
        if any(b <= a for a, b in itertools.pairwise(idx)):
            raise LoopError("a map's keyframe indices must increase")
        known = set(idx)
        for e in self.loops:
            if e.old not in known or e.new not in known:
                raise LoopError(f"the map's loop {e.old} -> {e.new} names a keyframe it lacks")

    @property
    def next_index(self) -> int:
        """The first keyframe index after the map's."""
        return self.keyframes[-1].record.index + 1 if self.keyframes else 0

    def to_arrays(self) -> tuple[dict[str, object], dict[str, NDArray[np.generic]]]:
        """The map as a header (JSON-able) and flat arrays (see :mod:`quadnav.io.loop_map`)."""
        recs = [k.record for k in self.keyframes]
        head: dict[str, object] = {
            "format": MAP_FORMAT, "version": MAP_VERSION, "keyframes": len(recs),
            "loops": len(self.loops), "vocabulary": self.vocabulary,
            "camera": {"name": self.camera.name, "width": self.camera.width,
                       "height": self.camera.height, "fx": self.camera.fx, "fy": self.camera.fy,
                       "cx": self.camera.cx, "cy": self.camera.cy},
        }  # fmt: skip
        arrays: dict[str, NDArray[np.generic]] = {
            "index": np.array([r.index for r in recs], np.int64),
            "t_ns": np.array([r.t_ns for r in recs], np.int64),
            "pose": _poses7([r.T_W_B for r in recs]),
            "T_B_C": _poses7([r.T_B_C for r in recs]),
            "cov_pose": np.array([r.cov_pose for r in recs], np.float64).reshape(-1, 6, 6),
            "n_keypoints": np.array([len(r.ids) for r in recs], np.int64),
            "ids": _cat([r.ids for r in recs], np.int64, (0,)),
            "uv_px": _cat([r.uv_px for r in recs], np.float64, (0, 2)),
            "xy": _cat([r.xy for r in recs], np.float64, (0, 2)),
            "descriptors": _cat([_desc(r) for r in recs], np.uint8, (0, 32)),
            "described": _cat([_ok(r) for r in recs], np.bool_, (0,)),
            "n_landmarks": np.array([len(r.landmark_ids) for r in recs], np.int64),
            "landmark_ids": _cat([r.landmark_ids for r in recs], np.int64, (0,)),
            "landmarks": _cat([r.landmarks_W for r in recs], np.float64, (0, 3)),
            "n_words": np.array([len(k.bow.words) for k in self.keyframes], np.int64),
            "words": _cat([k.bow.words for k in self.keyframes], np.int32, (0,)),
            "weights": _cat([k.bow.weights for k in self.keyframes], np.float64, (0,)),
            "n_nodes": np.array([len(k.direct.nodes) for k in self.keyframes], np.int64),
            "direct_nodes": _cat([k.direct.nodes for k in self.keyframes], np.int64, (0,)),
            "direct_offsets": _cat([k.direct.offsets for k in self.keyframes], np.int64, (0,)),
            "n_features": np.array([len(k.direct.features) for k in self.keyframes], np.int64),
            "direct_features": _cat([k.direct.features for k in self.keyframes], np.int64, (0,)),
            "loop_ends": np.array([[e.old, e.new] for e in self.loops], np.int64).reshape(-1, 2),
            "loop_pose": _poses7([e.T_old_new for e in self.loops]),
            "loop_scale": np.array([e.scale for e in self.loops], np.float64),
            "loop_cov": _loop_cov(self.loops),
        }
        camera = recs[0].camera if recs else self.camera.name
        head["camera_name_of_keyframes"] = camera
        return head, arrays

    @classmethod
    def from_arrays(cls, head: dict[str, object], a: dict[str, NDArray[np.generic]]) -> LoopMap:
        """The map of :meth:`to_arrays`; an inconsistent one is a one-line :class:`LoopError`
        (the caller names the file)."""
        try:
            return _from_arrays(head, a)
        except LoopError:
            raise
        except QuadnavError as exc:  # a record or an edge that does not hold together
            raise LoopError(f"inconsistent map ({exc})") from None
        except (KeyError, ValueError, TypeError, IndexError) as exc:
            raise LoopError(f"inconsistent map ({type(exc).__name__}: {exc})") from None


#: How many ulps :func:`_stable_quats` moves a quaternion's largest component at most (4 were
#: enough for each of 50,000 random rotations).
_MAX_ULPS = 16


def _poses7(poses: Sequence[Pose | None]) -> FloatArray:
    """Rows of x, y, z, qx, qy, qz, qw (None: a row of NaN), each quaternion one that reading
    back gives bit for bit (:func:`_stable_quats`): the round trip of a map is exact."""
    out = np.full((len(poses), 7), np.nan)
    have = [k for k, T in enumerate(poses) if T is not None]
    if have:
        out[have, :3] = [poses[k].p_A_B for k in have]  # type: ignore[union-attr]
        out[have, 3:] = _stable_quats(np.array([poses[k].R_A_B.as_quat() for k in have]))  # type: ignore[union-attr]
    return out


def _stable_quats(q: FloatArray) -> FloatArray:
    """Each quaternion (rows, unit) as one that scipy's normalisation leaves as it is: the row
    itself, or it with its largest component moved by the fewest ulps. Scipy normalises what
    it is given, and for about one rotation in three the result differs from the quaternion
    in its last bits; normalising that again may not come back (a walk of up to hundreds of
    steps, or a cycle), so a map saved, loaded and saved again differed in such a pose."""
    from scipy.spatial.transform import Rotation

    out = q.copy()
    todo = np.arange(len(q))
    big = np.argmax(np.abs(q), axis=1)
    for k in sorted(range(-_MAX_ULPS, _MAX_ULPS + 1), key=lambda k: (abs(k), k)):
        if not len(todo):
            break
        x = q[todo].copy()
        col = big[todo]
        v = x[np.arange(len(todo)), col]
        for _ in range(abs(k)):
            v = np.nextafter(v, np.inf if k > 0 else -np.inf)
        x[np.arange(len(todo)), col] = v
        ok = np.all(Rotation.from_quat(x).as_quat() == x, axis=1)
        out[todo[ok]] = x[ok]
        todo = todo[~ok]
    return out


def _pose_of(row: NDArray[np.generic]) -> Pose:
    v = np.asarray(row, np.float64)
    if not np.isfinite(v).all() or abs(np.linalg.norm(v[3:]) - 1.0) > 1e-6:
        raise LoopError(f"inconsistent map: a pose {v.tolist()} is not finite or not unit")
    return Pose.from_quat_xyzw(v[3:], v[:3])


def _cat(
    parts: list[NDArray[np.generic]], dtype: type, empty: tuple[int, ...]
) -> NDArray[np.generic]:
    return (
        np.concatenate([np.asarray(p, dtype) for p in parts]) if parts else np.zeros(empty, dtype)
    )


def _desc(r: KeyframeRecord) -> NDArray[np.uint8]:
    return r.descriptors if r.descriptors is not None else np.zeros((len(r.ids), 32), np.uint8)


def _ok(r: KeyframeRecord) -> NDArray[np.bool_]:
    if r.described is not None:
        return r.described
    return np.full(len(r.ids), r.descriptors is not None, bool)


def _loop_cov(loops: tuple[LoopEdge, ...]) -> FloatArray:
    """Each loop's covariance flattened into a row of 36 (NaN: none; a 4x4 fills 16)."""
    out = np.full((len(loops), 36), np.nan)
    for n, e in enumerate(loops):
        if e.cov is not None:
            out[n, : e.cov.size] = e.cov.ravel()
    return out


def _i64(x: NDArray[np.generic]) -> NDArray[np.int64]:
    return np.asarray(x, np.int64)


def _f64(x: NDArray[np.generic]) -> FloatArray:
    return np.asarray(x, np.float64)


def _splits(counts: NDArray[np.generic], total: int, what: str) -> list[slice]:
    c = np.asarray(counts, np.int64)
    if (c < 0).any() or int(c.sum()) != total:
        raise LoopError(f"inconsistent map: {what} counts sum to {int(c.sum())}, not {total}")
    ends = np.cumsum(c)
    return [slice(int(e - n), int(e)) for e, n in zip(ends, c, strict=True)]


def _from_arrays(head: dict[str, object], a: dict[str, NDArray[np.generic]]) -> LoopMap:
    cam = head["camera"]
    if not isinstance(cam, dict):
        raise LoopError("inconsistent map: its camera is not a table")
    camera = MapCamera(name=str(cam["name"]), width=int(cam["width"]), height=int(cam["height"]),
                       fx=float(cam["fx"]), fy=float(cam["fy"]), cx=float(cam["cx"]),
                       cy=float(cam["cy"]))  # fmt: skip
    n = len(a["index"])
    if int(str(head["keyframes"])) != n:
        raise LoopError(
            f"inconsistent map: {n} keyframes stored, its header says {head['keyframes']}"
        )
    kp = _splits(a["n_keypoints"], len(a["ids"]), "keypoint")
    lm = _splits(a["n_landmarks"], len(a["landmark_ids"]), "landmark")
    words = _splits(a["n_words"], len(a["words"]), "word")
    nodes = _splits(a["n_nodes"], len(a["direct_nodes"]), "direct-index node")
    offs = _splits(np.asarray(a["n_nodes"], np.int64) + 1, len(a["direct_offsets"]), "offset")
    feats = _splits(a["n_features"], len(a["direct_features"]), "direct-index feature")
    name = str(head.get("camera_name_of_keyframes", camera.name))
    keyframes = []
    for k in range(n):
        t_b_c = np.asarray(a["T_B_C"][k], np.float64)
        record = KeyframeRecord(
            index=int(a["index"][k]), t_ns=int(a["t_ns"][k]), reset_counter=MAP_FRAME,
            T_W_B=_pose_of(a["pose"][k]), cov_pose=np.asarray(a["cov_pose"][k], np.float64),
            camera=name, image=None, ids=_i64(a["ids"][kp[k]]), uv_px=_f64(a["uv_px"][kp[k]]),
            xy=_f64(a["xy"][kp[k]]), descriptors=np.asarray(a["descriptors"][kp[k]], np.uint8),
            described=np.asarray(a["described"][kp[k]], bool),
            landmark_ids=_i64(a["landmark_ids"][lm[k]]), landmarks_W=_f64(a["landmarks"][lm[k]]),
            T_B_C=None if np.isnan(t_b_c).all() else _pose_of(t_b_c),
        )  # fmt: skip
        bow = BowVector(np.asarray(a["words"][words[k]], np.int32),
                        np.asarray(a["weights"][words[k]], np.float64))  # fmt: skip
        direct = DirectIndex(nodes=np.asarray(a["direct_nodes"][nodes[k]], np.int64),
                             offsets=np.asarray(a["direct_offsets"][offs[k]], np.int64),
                             features=np.asarray(a["direct_features"][feats[k]], np.int64))  # fmt: skip
        keyframes.append(MapKeyframe(record=record, bow=bow, direct=direct))
    loops = []
    for ends, pose, scale, cov in zip(a["loop_ends"], a["loop_pose"], a["loop_scale"],
                                      a["loop_cov"], strict=True):  # fmt: skip
        c = np.asarray(cov, np.float64)
        size = int(np.isfinite(c).sum())
        m = None if size == 0 else c[:size].reshape(round(size**0.5), -1)
        loops.append(LoopEdge(old=int(ends[0]), new=int(ends[1]), T_old_new=_pose_of(pose),
                              scale=float(scale), cov=m))  # fmt: skip
    return LoopMap(keyframes=tuple(keyframes), loops=tuple(loops), camera=camera,
                   vocabulary=str(head["vocabulary"]))  # fmt: skip
