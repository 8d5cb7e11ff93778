"""Stereo and RGB-D visual SLAM of the ORB-SLAM2 class (issue 24): so far its frames (ORB in a
pyramid, stereo and RGB-D keypoints, ThDepth's close points) and its tracking (a constant
velocity model, projection search over the last keyframes' map points, pose-only
optimisation, loss detected) and the local bundle adjustment local mapping will run (GTSAM's stereo
and projection factors, held keyframes, outliers dropped). Local mapping itself, loop closing,
relocalization and maps come next."""

from quadnav.slam.config import SlamConfig
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
from quadnav.slam.tracking import StereoTracker, TrackResult, search_by_projection

__all__ = [
    "BundleProblem",
    "BundleResult",
    "Frame",
    "LocalMappingReport",
    "PoseFit",
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
