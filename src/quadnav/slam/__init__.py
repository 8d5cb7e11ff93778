"""Stereo and RGB-D visual SLAM of the ORB-SLAM2 class (issue 24): its frames (ORB in a
pyramid, stereo and RGB-D keypoints, ThDepth's close points), its tracking (a constant
velocity model, projection search over the covisible keyframes' map points, pose-only
optimisation, loss detected), local mapping (point culling, the local bundle adjustment in
GTSAM), relocalization on the map it keeps (bags of words, PnP), maps as arrays for a file
(``io/slam_map.py``) and localization only, behind the odometry interface
(:class:`SlamOdometry`, whose keyframe records a loop closer consumes). Keyframe culling, the
essential graph and a loop closing that corrects the map itself come next."""

from quadnav.slam.config import RelocalizationConfig, SlamConfig
from quadnav.slam.frame import Frame, StereoCamera, rgbd_frame, stereo_frame
from quadnav.slam.local_mapping import LocalMappingReport, local_mapping
from quadnav.slam.map import SlamKeyframe, SlamMap
from quadnav.slam.odometry import SlamOdometry
from quadnav.slam.optimizer import (
    BundleProblem,
    BundleResult,
    PoseFit,
    local_bundle_adjustment,
    optimize_pose,
)
from quadnav.slam.relocalization import KeyframeDatabase
from quadnav.slam.tracking import StereoTracker, TrackResult, search_by_projection

__all__ = [
    "BundleProblem",
    "BundleResult",
    "Frame",
    "KeyframeDatabase",
    "LocalMappingReport",
    "PoseFit",
    "RelocalizationConfig",
    "SlamConfig",
    "SlamKeyframe",
    "SlamMap",
    "SlamOdometry",
    "StereoCamera",
    "StereoTracker",
    "TrackResult",
    "local_bundle_adjustment",
    "local_mapping",
    "optimize_pose",
    "rgbd_frame",
    "search_by_projection",
    "stereo_frame",
]
