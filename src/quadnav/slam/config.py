"""The SLAM's settings (ORB-SLAM2's, and thesis 002's where it changed them)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from quadnav.errors import SlamError
from quadnav.vision.orb import OrbConfig
from quadnav.vision.stereo_match import StereoConfig

__all__ = ["LoopClosingConfig", "RelocalizationConfig", "SlamConfig"]


@dataclass(frozen=True, slots=True, kw_only=True)
class LoopClosingConfig:
    """Loop closing's settings (:mod:`quadnav.slam.loop_closing`). ``covisible``: how many covisible keyframes count as the keyframe's
    neighbourhood (excluded as candidates) and as the candidate's (whose points are matched);
    ``max_hamming``, ``ratio``, ``min_matches``, ``ransac_px``: the descriptor matching and PnP;
    ``loop_sigma_m``, ``loop_sigma_rad``: the loop edge's; ``edge_sigma_m``,
    ``edge_sigma_rad``: the essential graph's other edges; ``max_drift_*``: the largest
    correction a loop may ask (m, plus a fraction of the shortest way from the old keyframe
    through the map; deg): a stereo SLAM drifts about 1 % of its path, a repeated texture asks
    for its period."""

    enabled: bool = True
    min_gap_keyframes: int = 20
    consistency: int = 2
    covisible: int = 10
    max_hamming: int = 64
    ratio: float = 0.8
    min_matches: int = 20
    ransac_px: float = 3.0
    min_inliers: int = 40
    covisibility_edge: int = 100
    loop_sigma_m: float = 0.003
    loop_sigma_rad: float = 0.002
    edge_sigma_m: float = 0.01
    edge_sigma_rad: float = 0.005
    max_drift_m: float = 0.1
    max_drift_fraction: float = 0.03
    max_drift_deg: float = 10.0

    def __post_init__(self) -> None:
        ints = (self.min_gap_keyframes, self.consistency, self.covisible, self.min_matches,
                self.min_inliers, self.covisibility_edge)  # fmt: skip
        if min(ints) < 1 or not 0 <= self.max_hamming <= 256 or not 0 < self.ratio <= 1:
            raise SlamError("LoopClosingConfig: counts >= 1, max_hamming 0-256, ratio in (0, 1]")
        sig = (self.ransac_px, self.loop_sigma_m, self.loop_sigma_rad, self.edge_sigma_m,
               self.edge_sigma_rad, self.max_drift_m, self.max_drift_fraction,
               self.max_drift_deg)  # fmt: skip
        if not all(np.isfinite(s) and s > 0 for s in sig):
            raise SlamError("LoopClosingConfig: ransac_px, the sigmas and max_drift_* must be > 0")


@dataclass(frozen=True, slots=True, kw_only=True)
class RelocalizationConfig:
    """The relocalization's settings (:mod:`quadnav.slam.relocalization`). ``ransac_px``: PnP's inlier threshold at level 0 (px);
    ``min_pnp_inliers``: what a candidate's PnP needs before the local map is tried;
    ``ambiguous_*``: a second candidate keeping this share of the best one's inliers with the
    camera this far (m) or turned this much (deg) from it makes the place ambiguous (a texture
    that repeats): no relocalization on that frame."""

    max_candidates: int = 5
    min_score_ratio: float = 0.75
    max_hamming: int = 64
    ratio: float = 0.8
    min_matches: int = 15
    ransac_px: float = 3.0
    min_pnp_inliers: int = 12
    min_inliers: int = 50
    ambiguous_ratio: float = 0.8
    ambiguous_m: float = 0.3
    ambiguous_deg: float = 10.0

    def __post_init__(self) -> None:
        if self.max_candidates < 1 or self.min_matches < 6 or self.min_pnp_inliers < 6:
            raise SlamError("RelocalizationConfig: max_candidates >= 1, min matches/inliers >= 6")
        if not 0 < self.min_score_ratio <= 1 or not 0 < self.ratio <= 1:
            raise SlamError("RelocalizationConfig: min_score_ratio and ratio must lie in (0, 1]")
        amb = (self.ambiguous_ratio, self.ambiguous_m, self.ambiguous_deg)
        if not all(np.isfinite(a) and a > 0 for a in amb):
            raise SlamError("RelocalizationConfig: ambiguous_ratio, _m and _deg must be > 0")
        if not 0 <= self.max_hamming <= 256 or not self.ransac_px > 0 or self.min_inliers < 1:
            raise SlamError(
                "RelocalizationConfig: max_hamming 0-256, ransac_px > 0, min_inliers >= 1"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class SlamConfig:
    """``orb``: the extractor (1,200 features, thesis 002 section 5.7); ``stereo``: the
    matcher; ``th_depth_baselines``: ThDepth (ORB-SLAM2's 40; 22 was best on the thesis's
    Jetson); ``init_min_points``: stereo points the first frame needs (ORB-SLAM2 asks 500 keypoints
    of any kind; 300 with a depth is about what 500 of EuRoC's come with);
    ``search_radius_px``: the projection search's window at level 0 (wider once when too few
    match); ``max_hamming``: a projection match's descriptor distance (TH_HIGH);
    ``min_inliers``: below this after the pose optimisation the tracking is lost;
    ``keyframe_*``: the thesis's keyframe rules (chapter 3; its 90 % is ORB-SLAM's monocular
    ratio, ORB-SLAM2's code takes 0.75 for a stereo or RGB-D camera): not within
    ``keyframe_max_frames`` of a relocalization; when the frame tracks under
    ``keyframe_ratio`` of its reference keyframe's points (those ``keyframe_min_observers``
    keyframes see: ORB-SLAM2's 3; with fewer, a map whose points are fused counts most of them
    and keyframes come twice as often), or fewer than ``close_tracked`` close points while
    ``close_untracked``
    more could be made (ORB-SLAM2's stereo rule), if it tracks at least
    ``keyframe_min_tracked``; ``local_keyframes``: the map points of so many keyframes are
    projected into each frame (the newest, and those that see most of the last frame's
    points); ``local_ba_keyframes``: the newest keyframe and its most covisible ones adjusted
    after each keyframe; ``fuse_neighbours``: the new keyframe's points fused with those of
    its covisible keyframes after each keyframe (ORB-SLAM2's ``SearchInNeighbors``);
    ``global_ba``: every keyframe and point adjusted after a loop is
    closed (ORB-SLAM2 does it in a thread; here inline), over the newest
    ``global_ba_keyframes`` keyframes at most, the ``global_ba_held`` older ones that see the
    most of their points held (its cost grew faster than the map, 18 s at 190 keyframes, and it
    stops the tracking while it runs; in a place a run keeps coming back to, every older
    keyframe sees the newest ones' points); ``final_ba``: the same once more when
    the run ends (the first ``keyframes(final=True)``), so that the final map, its trajectory and
    a saved map are adjusted over every keyframe (the causal estimate is not touched; a
    localization-only run adjusts nothing), over the newest ``final_ba_keyframes`` keyframes
    at most (``global_ba_held`` older ones that see their points held: a long run's end stays
    bounded), with
    a stereo pair's rectified intrinsics estimated too when ``final_ba_intrinsics`` (a
    calibration a little off what is stated shows as a distorted map; written to the run
    folder's ``final_intrinsics.json``);
    ``relocalization``: after a loss
    (:mod:`quadnav.slam.relocalization`); ``loop_closing``: :mod:`quadnav.slam.loop_closing`."""

    orb: OrbConfig = field(default_factory=OrbConfig)
    stereo: StereoConfig = field(default_factory=StereoConfig)
    th_depth_baselines: float = 40.0
    init_min_points: int = 300
    search_radius_px: float = 15.0
    max_hamming: int = 100
    min_inliers: int = 30
    keyframe_max_frames: int = 20
    keyframe_ratio: float = 0.75
    keyframe_min_tracked: int = 50
    keyframe_min_observers: int = 3
    keyframe_every: int = 0
    close_tracked: int = 100
    close_untracked: int = 70
    local_keyframes: int = 10
    local_mapping: bool = True
    local_ba_keyframes: int = 5
    fuse_neighbours: bool = True
    global_ba: bool = True
    global_ba_keyframes: int = 60
    global_ba_held: int = 20
    final_ba: bool = True
    final_ba_keyframes: int = 300
    final_ba_intrinsics: bool = True
    relocalization: RelocalizationConfig = field(default_factory=RelocalizationConfig)
    loop_closing: LoopClosingConfig = field(default_factory=LoopClosingConfig)

    def __post_init__(self) -> None:
        if not self.th_depth_baselines > 0 or not self.search_radius_px > 0:
            raise SlamError("SlamConfig: th_depth_baselines and search_radius_px must be > 0")
        if not 0 < self.keyframe_ratio <= 1:
            raise SlamError(
                f"SlamConfig.keyframe_ratio must lie in (0, 1], got {self.keyframe_ratio}"
            )
        ints = (
            "init_min_points",
            "min_inliers",
            "keyframe_max_frames",
            "keyframe_min_tracked",
            "local_keyframes",
            "local_ba_keyframes",
            "keyframe_min_observers",
            "global_ba_keyframes",
            "global_ba_held",
            "final_ba_keyframes",
        )
        if self.keyframe_every < 0:
            raise SlamError(f"SlamConfig.keyframe_every must be >= 0, got {self.keyframe_every}")  # fmt: skip
        if any(getattr(self, k) < 1 for k in ints) or not 0 <= self.max_hamming <= 256:
            raise SlamError(f"SlamConfig: {', '.join(ints)} must be >= 1, max_hamming 0-256")
