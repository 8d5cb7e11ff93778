"""The SLAM's relocalization (ORB-SLAM2's ``Relocalization`` and ``KeyFrameDatabase``): the
keyframes' bags of words in a place database (:class:`quadnav.place.Database` over the shipped
vocabulary); a frame whose tracking was lost asks it for the keyframes that look most like it
(those scoring at least ``min_score_ratio`` of the best, ``max_candidates`` at most), and for
each, best first, its map points are matched to the frame's keypoints by descriptor (the
nearest within ``max_hamming`` bits and under ``ratio`` times the second nearest) and the
camera's pose is found by PnP in RANSAC (:func:`quadnav.geometry.multiview.pnp`) on them. The
tracker then confirms the pose on the local map of that keyframe (a projection search and the
pose optimisation, as it tracks) and needs ``min_inliers`` there (ORB-SLAM2: 50).

The map is kept: a relocalized frame is in the same world as before the loss."""

from __future__ import annotations

import numpy as np

from quadnav.errors import SlamError
from quadnav.geometry.rotations import Pose
from quadnav.slam.config import RelocalizationConfig
from quadnav.slam.frame import Frame
from quadnav.slam.map import SlamKeyframe, SlamMap

__all__ = ["KeyframeDatabase", "pnp_candidates"]


class KeyframeDatabase:
    """The keyframes' bags of words (entry ``k`` is keyframe ``k``)."""

    def __init__(self) -> None:
        from quadnav.place import Database, default_vocabulary

        self.db = Database(default_vocabulary())

    def __len__(self) -> int:
        return len(self.db)

    def add(self, kf: SlamKeyframe) -> None:
        if kf.index != len(self.db):
            raise SlamError(f"keyframe {kf.index} added out of order ({len(self.db)} expected)")
        self.db.add(kf.frame.features.descriptors)

    def candidates(self, frame: Frame, config: RelocalizationConfig) -> list[int]:
        """The keyframes that look most like ``frame``, best first."""
        if len(self.db) == 0 or len(frame) == 0:
            return []
        bow, _ = self.db.transform(frame.features.descriptors)
        found = self.db.query(bow, max_results=config.max_candidates)
        if not found:
            return []
        best = found[0].score
        return [r.entry for r in found if r.score >= config.min_score_ratio * best]


def pnp_candidates(
    frame: Frame, slam_map: SlamMap, keyframes: list[int], config: RelocalizationConfig
) -> list[tuple[int, Pose]]:
    """For each candidate keyframe in turn, the camera's ``T_C_W`` that PnP finds from its map
    points' descriptor matches (candidates that give none are left out)."""
    from quadnav.geometry.multiview import pnp
    from quadnav.place.verification import match_descriptors

    c, f = frame.camera, frame.features
    xy = np.column_stack([(f.uv_px[:, 0] - c.cx) / c.fx, (f.uv_px[:, 1] - c.cy) / c.fy])
    out: list[tuple[int, Pose]] = []
    for k in keyframes:
        _, ids = slam_map.keyframes[k].observed
        ids = ids[~slam_map.bad[ids]]
        ia, ib = match_descriptors(slam_map.descriptors[ids], f.descriptors,
                                   max_hamming=config.max_hamming, ratio=config.ratio)  # fmt: skip
        if len(ia) < config.min_matches:
            continue
        res = pnp(slam_map.X_W[ids[ia]], xy[ib], ransac_threshold=config.ransac_px / c.fx,
                  min_points=config.min_pnp_inliers, iterations=300, seed=k)  # fmt: skip
        if res is not None:
            out.append((k, res.T_W_C.inverse()))
    return out
