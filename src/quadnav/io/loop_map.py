"""Loop closure's map on disk (``quadnav vio --save-map DIR`` / ``--load-map DIR``).

A map is a folder of two files:

- ``map.json``: ``format`` (``quadnav-loop-map``), ``version`` (1), the number of ``keyframes``
  and ``loops``, the ``vocabulary``'s fingerprint (the bags of words are only good with it),
  the ``camera`` (name, image size, fx, fy, cx, cy in pixels), and ``quadnav`` (the version
  that wrote it).
- ``keyframes.npz`` (NumPy, uncompressed, no pickles): per keyframe ``index``, ``t_ns``,
  ``pose`` (x, y, z, qx, qy, qz, qw of the body in the map: ENU, metres), ``T_B_C`` (the
  camera's extrinsic, NaN: the rig's), ``cov_pose`` (6x6, body frame, rotation first); its
  keypoints concatenated over keyframes with ``n_keypoints`` each: ``ids``, ``uv_px``
  (distorted pixels), ``xy`` (undistorted normalised), ``descriptors`` (32 bytes, ORB/BRIEF),
  ``described``; its landmarks with ``n_landmarks`` each: ``landmark_ids``, ``landmarks``
  (map frame, m); its bag of words with ``n_words`` each: ``words``, ``weights``; its direct
  index with ``n_nodes`` and ``n_features`` each: ``direct_nodes``, ``direct_offsets``
  (``n_nodes + 1`` each), ``direct_features``; and the loops: ``loop_ends`` (old, new keyframe
  index), ``loop_pose`` (new in old's body, as ``pose``), ``loop_scale``, ``loop_cov`` (36 per
  loop, the covariance's entries row by row then NaN; all NaN: none).

A map is written to a temporary folder and renamed into place, so a folder that exists is
complete. A missing, truncated, corrupt or foreign map, one of another version, vocabulary or
camera is a one-line :class:`~quadnav.errors.LoopError` naming the folder.
"""

from __future__ import annotations

from pathlib import Path

from quadnav.errors import LoopError
from quadnav.io.map_folder import read_map_folder, write_map_folder
from quadnav.loop.map import MAP_FORMAT, MAP_VERSION, LoopMap, MapCamera

__all__ = ["load_loop_map", "save_loop_map"]

_ARRAYS = "keyframes.npz"


def save_loop_map(folder: Path, loop_map: LoopMap) -> Path:
    """Write ``loop_map`` to ``folder`` (replacing a map there; refusing a folder that holds
    anything else)."""
    head, arrays = loop_map.to_arrays()
    return write_map_folder(folder, head, arrays, archive=_ARRAYS, error=LoopError)


def load_loop_map(
    folder: Path, *, vocabulary: str | None = None, camera: MapCamera | None = None,
    option: str = "--load-map",
) -> LoopMap:  # fmt: skip
    """The map in ``folder``, checked against the ``vocabulary`` fingerprint and the ``camera``
    of the run that will use it (None: not checked); ``option``: the user's option that named
    it, for the errors."""
    where = f"{option} {folder}"
    head, arrays = read_map_folder(folder, fmt=MAP_FORMAT, version=MAP_VERSION, archive=_ARRAYS,
                                   error=LoopError, option=option)  # fmt: skip
    if vocabulary is not None and head.get("vocabulary") != vocabulary:
        raise LoopError(
            f"{where}: made with another vocabulary ({head.get('vocabulary')}, "
            f"this run's {vocabulary})"
        )
    try:
        loop_map = LoopMap.from_arrays(head, arrays)
    except LoopError as exc:
        raise LoopError(f"{where}: {exc}") from None
    if camera is not None and (why := loop_map.camera.mismatch(camera)) is not None:
        raise LoopError(f"{where}: made with another camera ({why})")
    return loop_map
