"""The SLAM behind the odometry interface (:class:`quadnav.odometry.VisualOdometry`), so that the
runner that drives the VIO (``experiments/odometry_run.py``: run folder, trajectory, metrics,
report) drives it too.

A stereo rig's two cameras are rectified once (:class:`~quadnav.vision.stereo.StereoRectifier`);
a frame of the first camera waits for its partner of the same time, and the pair is rectified,
made into a :class:`~quadnav.slam.frame.Frame` and tracked. An RGB-D rig's camera (a pinhole:
undistorted images) is tracked with the depth image of the same time that ``depth`` gives (a
missing one is counted, ``missing_depth``), its keypoints given ORB-SLAM2's virtual right
coordinate over a baseline of ``RGBD_BASELINE_M``. The odometry's world is the
vehicle's frame (the rig's ``T_V_B``) at the first tracked frame: a SLAM without an IMU knows no
gravity, so its world is level only if the vehicle started level (on the ground, as usual);
otherwise evaluate it after an SE(3) alignment. The body's pose is the rectified left camera's
through the rig's extrinsic. IMU samples are not used. Frames of
another camera, a right frame without its left, an image that cannot be read: rejected and
counted. A left frame whose partner never comes (the next left frame, or a later right one,
comes first) is tracked as mono and counted (``stereo_unpaired``). A loss is an event (``failure``) and the states stop
until the tracker relocalizes on the map it kept (an event ``reinitialized``; the world is the
same, so the reset counter stays).

Each keyframe, once it has left the local bundle adjustment (``local_ba_keyframes`` newer ones),
is published as a :class:`~quadnav.odometry.KeyframeRecord` for a loop closer or a map (its
keypoints in the rig's left camera: ``uv_px`` through its lens, ``xy`` undistorted; ids: the map
point a keypoint observes, or below -1,000,000 for none; its landmarks: those points in the
odometry's world). On a map saved before (``slam_map``, made with the same rectified camera) the
odometry starts lost and relocalizes; its world is the map's (the world of the run that made
it). ``mapping=False``: localization only. A map made with another camera (focal lengths,
centre or baseline more than 2 % apart) is a :class:`~quadnav.errors.SlamError`.

The rectified left camera's intrinsics the SLAM measures in are the rectification's, unless
``intrinsics`` (fx, fy, cx, cy) gives others for the same rectification (a stereo rig's): those
an earlier run's final adjustment estimated (its ``final_intrinsics.json``), which hold the
calibration's error that the rectification cannot. ``fix`` (with those ``intrinsics``, its
left camera's) folds the rest of what that adjustment found into the rectification (the
distortion the stated lens model left in each image, the right camera, the rig's turn:
:class:`~quadnav.vision.stereo.RectificationFix`), so that the pair comes out as the ideal
rectified pair of the camera found. A loaded map is tracked in the camera it
was saved with (a map saved after a self-calibrating final adjustment: the estimated one);
:attr:`SlamOdometry.map_camera` is the camera the map is in now.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import QuadnavError, SampleError, SlamError
from quadnav.geometry.rotations import Pose
from quadnav.geometry.trajectory import Trajectory
from quadnav.messages import ImageFrame, ImuSample
from quadnav.odometry import (
    EventKind,
    FrameFeatures,
    KeyframeRecord,
    OdometryEvent,
    OdometryState,
    StageTiming,
)
from quadnav.rig import Rig
from quadnav.slam.config import SlamConfig
from quadnav.slam.frame import Frame, StereoCamera, rgbd_frame, stereo_frame
from quadnav.slam.local_mapping import global_bundle_adjustment
from quadnav.slam.map import SlamKeyframe, SlamMap
from quadnav.slam.tracking import StereoTracker, TrackResult
from quadnav.vision.orb import OrbExtractor
from quadnav.vision.stereo_match import StereoKeypoints
from quadnav.vision.tracking import as_grey

if TYPE_CHECKING:
    from quadnav.slam.optimizer import SelfCalibration
    from quadnav.vision.stereo import RectificationFix, StereoRectifier

FloatArray = NDArray[np.float64]

__all__ = ["SlamOdometry"]

#: the map's own error, which the SLAM does not estimate: 1 cm and 0.5 degree, body frame. A
#: state's covariance is its tracking's (the pose-only fit's) plus this; a keyframe record's is
#: this. (The tracking's alone is the pose against the map: on realistic V1_02 its NEES / 6 was
#: 1,382 against the truth, where the map's error dominates; on ideal renders 1.25.)
_COV_POSE = np.diag([np.radians(0.5) ** 2] * 3 + [0.01**2] * 3)
#: a keypoint that observes no map point has the id ``-(NO_POINT + k)`` (k: its row)
NO_POINT = 1_000_000
#: an RGB-D camera's virtual baseline (m): ThDepth and the right coordinate's weight are in it
#: (a RealSense D435's stereo baseline, 50 mm; ORB-SLAM2's TUM settings use 40 / fx = 77 mm)
RGBD_BASELINE_M = 0.05
#: an RGB-D rig's depth image (float metres, inf or 0 for no reading) at a time, or None
DepthSource = Callable[[int], "NDArray[np.floating] | None"]


class SlamOdometry:
    """The SLAM as an odometry (see the module) on a stereo ``rig``, or on an RGB-D one whose
    depth images ``depth`` gives by time. Its world is not ``levelled``: it is its first pose."""

    levelled = False

    def __init__(
        self, rig: Rig, config: SlamConfig | None = None, *, slam_map: SlamMap | None = None,
        map_camera: StereoCamera | None = None, mapping: bool = True,
        depth: DepthSource | None = None,
        intrinsics: tuple[float, float, float, float] | None = None,
        fix: RectificationFix | None = None,
    ) -> None:  # fmt: skip
        self.config = config or SlamConfig()
        #: an earlier run's calibration folded into the rectification (None: the stated one's)
        self.fix = fix
        self._depth = depth
        self.rectifier: StereoRectifier | None = None
        self.camera: StereoCamera
        self.T_B_C: Pose
        self._R0 = np.eye(3)  # (the rectification's turn of the left camera: x_rect = R0 x)
        if rig.stereo:
            self._stereo_rig(rig)
        elif rig.depth is not None:
            self._rgbd_rig(rig)
        else:
            raise SlamError(
                f"rig {rig.name!r} has one camera and no depth: the SLAM needs a stereo or an "
                "RGB-D rig"
            )
        self.T_V_B = rig.T_V_B
        #: the camera the rectification gives (keypoints are mapped back to the lens through it)
        self.rectified = self.camera
        if intrinsics is not None:
            self.camera = _given_intrinsics(self.camera, intrinsics, stereo=rig.stereo)
        if fix is not None:
            self.rectifier = self._corrected(fix, intrinsics)
        if slam_map is not None:
            _check_same_camera(self.camera, map_camera)
            assert map_camera is not None
            if intrinsics is None:  # (the map's own: it was adjusted in it)
                self.camera = map_camera
        self.extractor = OrbExtractor(self.config.orb)
        self.tracker = StereoTracker(self.config, slam_map=slam_map, mapping=mapping)
        # the odometry's world from the SLAM's (the first keyframe's rectified left camera)
        self.T_O_S = self.T_V_B @ self.T_B_C
        self._published = len(self.tracker.map.keyframes)  # (a loaded map's are not this run's)
        self._images: dict[int, ImageFrame] = {}
        self._pending: ImageFrame | None = None
        self._initialized = False
        self._resets = 0  # (raised at each loop closed: the output jumps)
        self._last: OdometryState | None = None
        self._last_features: FrameFeatures | None = None
        self._events: list[OdometryEvent] = []
        self._rejected: Counter[str] = Counter()
        self._seconds: dict[str, float] = {}
        self._calls: Counter[str] = Counter()
        self._finished = False  # (the run's end: the final bundle adjustment done)
        #: what the final adjustment found with the map (None: not estimated): the rectified
        #: pair's pinholes, the distortion left in its images, the rig
        self.final_calibration: SelfCalibration | None = None

    def _final_adjustment(self) -> None:
        """At the run's end (``config.final_ba``, while mapping): every keyframe and point
        adjusted once more (:func:`~quadnav.slam.local_mapping.global_bundle_adjustment`), timed
        as the stage ``final_ba``; a failed solve leaves the map as it was, counted
        (``final_ba_failed``)."""
        if not (self.config.final_ba and self.tracker.mapping):
            return
        t0 = time.perf_counter()
        try:
            done = global_bundle_adjustment(
                self.tracker.map,
                newest=self.config.final_ba_keyframes,
                max_held=self.config.global_ba_held,
                intrinsics=self.config.final_ba_intrinsics and self.rectifier is not None,
            )  # fmt: skip  (a stereo pair's: an RGB-D camera's right one is virtual)
            self.final_calibration = done.calibration
        except (RuntimeError, ValueError, np.linalg.LinAlgError):  # (GTSAM: indeterminant)
            self._rejected["final_ba_failed"] += 1  # (the map as it was: the run's end stands)
        self._time("final_ba", time.perf_counter() - t0)

    def _stereo_rig(self, rig: Rig) -> None:
        from quadnav.vision.stereo import StereoRectifier

        self.rectifier = StereoRectifier(rig)
        K = self.rectifier.K
        self.camera = StereoCamera(fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]),
                                   cy=float(K[1, 2]), baseline_m=self.rectifier.baseline_m)  # fmt: skip
        self.left = rig.cameras[0]
        self._R0 = self.rectifier.R0
        # the rectified left camera in the body: the original one turned by R0
        self.T_B_C = self.left.T_B_C @ Pose(Rotation.from_matrix(self._R0.T), np.zeros(3))
        self._names: tuple[str, ...] = (self.left.name, rig.cameras[1].name)

    def _rgbd_rig(self, rig: Rig) -> None:
        assert rig.depth is not None
        self.left = rig.camera(rig.depth.camera)
        if self._depth is None:
            raise SlamError(f"rig {rig.name!r} is RGB-D: the SLAM needs its depth images (depth=)")
        if self.left.camera.distorted:
            raise SlamError(
                f"rig {rig.name!r}: RGB-D with a distorted lens is not supported yet (undistort "
                "the images and give a pinhole camera)"
            )
        K = self.left.camera.K
        self.camera = StereoCamera(fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]),
                                   cy=float(K[1, 2]), baseline_m=RGBD_BASELINE_M)  # fmt: skip
        self.T_B_C = self.left.T_B_C
        self._names = (self.left.name,)

    # -- the odometry interface -------------------------------------------------------------
    @property
    def cameras(self) -> tuple[str, ...]:
        return self._names

    def push(self, sample: ImuSample | ImageFrame) -> OdometryState | None:
        if isinstance(sample, ImuSample):
            return None
        if self.rectifier is None:  # (RGB-D: one camera and its depth)
            if sample.camera != self._names[0]:
                self._rejected["other_camera"] += 1
                return None
            return self._frame(sample, lambda: self._rgbd_frame(sample))
        if sample.camera == self._names[0]:
            out = self._alone()  # (the pending left frame's partner never came)
            self._pending = sample
            return out
        if sample.camera != self._names[1]:
            self._rejected["other_camera"] += 1
            return None
        left = self._pending
        if left is None or sample.t_ns < left.t_ns:  # (a right frame without its left)
            self._rejected["unpaired_frames"] += 1
            return None
        if left.t_ns != sample.t_ns:
            self._rejected["unpaired_frames"] += 1
            return self._alone()
        self._pending = None
        return self._frame(left, lambda: self._stereo_frame(left, sample))

    def _alone(self) -> OdometryState | None:
        """The pending left frame tracked as mono (no stereo points: it tracks, it makes no
        point), counted ``stereo_unpaired``."""
        left, self._pending = self._pending, None
        if left is None:
            return None
        self._rejected["stereo_unpaired"] += 1
        return self._frame(left, lambda: self._mono_frame(left))

    def keyframes(self, *, final: bool = False) -> Sequence[KeyframeRecord]:
        if final and not self._finished:
            self._finished = True
            self._final_adjustment()
        kfs = self.tracker.map.keyframes
        upto = len(kfs) if final else len(kfs) - self.config.local_ba_keyframes
        out = [self._record(kf) for kf in kfs[self._published : max(upto, self._published)]]
        self._published = max(self._published, upto)
        for rec in out:
            self._images.pop(rec.index, None)
        return out

    def final_trajectory(self) -> Trajectory:
        """Every tracked frame's body pose through its reference keyframe's pose now (the
        local bundle adjustments and loop closings since moved it; ORB-SLAM2's saved
        trajectory): not causal (see :class:`~quadnav.odometry.RefinedTrajectory`)."""
        t, T_W_C = self.tracker.final_poses()
        T = self.T_O_S.matrix() @ T_W_C @ self.T_B_C.inverse().matrix()
        q = Rotation.from_matrix(T[:, :3, :3]).as_quat() if len(T) else np.zeros((0, 4))
        return Trajectory(t_ns=t, p_W_B=T[:, :3, 3], q_W_B_xyzw=q, name="final")

    def newest_keyframe(self) -> KeyframeRecord | None:
        kfs = self.tracker.map.keyframes
        if len(kfs) == 0 or kfs[-1].index < self._published:
            return None
        return self._record(kfs[-1])

    def _corrected(
        self, fix: RectificationFix, intrinsics: tuple[float, float, float, float] | None
    ) -> StereoRectifier:
        """The rectification with ``fix`` folded in; ``intrinsics`` must be its left camera's
        (the camera the corrected pair is in)."""
        if self.rectifier is None:
            raise SlamError("fix: a stereo rig's rectification; this rig is RGB-D")
        K = np.asarray(fix.K_left)
        if intrinsics is None or not np.allclose(
            intrinsics, (K[0, 0], K[1, 1], K[0, 2], K[1, 2]), rtol=0.0, atol=1e-9
        ):
            raise SlamError("fix: the intrinsics given must be its left camera's")
        return self.rectifier.corrected(fix)

    @property
    def final_intrinsics(self) -> tuple[float, float, float, float, float] | None:
        """The left rectified camera's ``(fx, fy, cx, cy, fx b)`` as the final adjustment
        estimated them (None: not estimated)."""
        cal = self.final_calibration
        return None if cal is None else cal.intrinsics

    @property
    def slam_map(self) -> SlamMap:
        return self.tracker.map

    @property
    def map_camera(self) -> StereoCamera:
        """The camera the map is in now: the one tracked with, or the one the final adjustment
        estimated with the map (a saved map keeps it)."""
        if self.final_intrinsics is None:
            return self.camera
        fx, fy, cx, cy, _ = self.final_intrinsics
        return StereoCamera(fx=fx, fy=fy, cx=cx, cy=cy, baseline_m=self.camera.baseline_m)

    @property
    def events(self) -> tuple[OdometryEvent, ...]:
        return tuple(self._events)

    @property
    def last_features(self) -> FrameFeatures | None:
        """The last frame's keypoints tracked on the map (ids: their map points), in the left
        camera's image through its lens; None when it was not tracked."""
        return self._last_features

    @property
    def rejected(self) -> Mapping[str, int]:
        return dict(self._rejected)

    def timing(self) -> StageTiming:
        return StageTiming(stages=tuple((k, self._seconds[k], self._calls[k]) for k in self._calls))

    # -- a frame -------------------------------------------------------------------------------
    def _stereo_frame(self, left: ImageFrame, right: ImageFrame) -> Frame:
        assert self.rectifier is not None
        L, R = self.rectifier.rectify(left.image(), right.image())
        return stereo_frame(left.t_ns, L, R, self.camera, self.extractor, self.config)

    def _mono_frame(self, left: ImageFrame) -> Frame:
        import cv2

        assert self.rectifier is not None
        img = left.image()
        if img.shape[1::-1] != self.rectifier.size:
            raise SampleError(
                f"{left.camera} image at t_ns={left.t_ns}: not the calibration's size"
            )
        (m1, m2), _ = self.rectifier.maps
        L = np.asarray(cv2.remap(as_grey(img), m1, m2, cv2.INTER_LINEAR), np.uint8)
        f, _levels = self.extractor.extract(L)
        none = np.full(len(f), -1.0)
        keys = StereoKeypoints(u_right=none, depth_m=none.copy())
        return Frame(t_ns=left.t_ns, features=f, stereo=keys, close=np.zeros(len(f), bool),
                     camera=self.camera)  # fmt: skip

    def _rgbd_frame(self, image: ImageFrame) -> Frame | None:
        assert self._depth is not None
        depth = self._depth(image.t_ns)
        if depth is None:
            self._rejected["missing_depth"] += 1
            return None
        if depth.shape[:2] != image.image().shape[:2]:
            raise SampleError(f"depth at t_ns={image.t_ns}: {depth.shape}, not the image's size")
        return rgbd_frame(image.t_ns, image.image(), depth, self.camera, self.extractor,
                          self.config)  # fmt: skip

    def _frame(self, left: ImageFrame, make: Callable[[], Frame | None]) -> OdometryState | None:
        t0 = time.perf_counter()
        try:
            frame = make()
        except QuadnavError:
            self._rejected["unreadable_images"] += 1
            return None
        if frame is None:
            return None
        t1 = time.perf_counter()
        before = self.tracker.state
        refused = len(self.tracker.loop_closer.refusals)
        result = self.tracker.track(frame)
        self._time("frame", t1 - t0)
        self._time("track", time.perf_counter() - t1)
        if result.state == "lost" and before != "lost":
            self._events.append(
                OdometryEvent(t_ns=left.t_ns, kind="failure", detail="tracking lost")
            )
        for detail in self.tracker.loop_closer.refusals[refused:]:
            self._events.append(OdometryEvent(t_ns=left.t_ns, kind="loop_rejected", detail=detail))
        self._last_features = None if result.T_W_C is None else self._tracked(frame, result)
        if result.T_W_C is None:
            return None
        if result.keyframe:
            self._images[len(self.tracker.map.keyframes) - 1] = left
        self._note(left.t_ns, result.relocalized_on)
        if result.loop is not None:
            lp = result.loop
            self._resets += 1
            self._events.append(OdometryEvent(
                t_ns=left.t_ns, kind="loop",
                detail=f"keyframe {lp.new} to {lp.old}: {lp.inliers} inliers, moved "
                f"{lp.moved_m:.3f} m, {math.degrees(lp.turned_rad):.2f} deg, {lp.fused} points fused",
            ))  # fmt: skip
        T_W_B = self.T_O_S @ result.T_W_C @ self.T_B_C.inverse()
        v = np.zeros(3)
        if self._last is not None and left.t_ns > self._last.t_ns:
            v = (T_W_B.p_A_B - self._last.T_W_B.p_A_B) / ((left.t_ns - self._last.t_ns) * 1e-9)
        self._last = OdometryState(
            t_ns=left.t_ns, T_W_B=T_W_B, v_W_B=v, gyro_bias=np.zeros(3), accel_bias=np.zeros(3),
            cov_pose=self._cov_body(result.cov_C), cov_v=np.eye(3) * 0.05**2,
            keyframe=result.keyframe,
            reset_counter=self._resets,
            tracked=result.inliers,
            quality=int(min(100, 100 * result.inliers / max(self.config.orb.n_features / 4, 1))),
        )  # fmt: skip
        return self._last

    def _cov_body(self, cov_C: NDArray[np.float64] | None) -> NDArray[np.float64]:
        """The tracked pose's covariance (camera frame) in the body frame plus the map's."""
        if cov_C is None:
            return _COV_POSE
        Ad = self.T_B_C.adjoint()
        cov = Ad @ cov_C @ Ad.T + _COV_POSE
        return np.asarray(0.5 * (cov + cov.T), np.float64)

    def _note(self, t_ns: int, relocalized_on: int | None) -> None:
        """The events of a frame tracked: the first, or one relocalized after a loss."""
        if relocalized_on is not None:
            detail = f"relocalized on keyframe {relocalized_on}"
            kind: EventKind = "reinitialized" if self._initialized else "initialized"
            self._events.append(OdometryEvent(t_ns=t_ns, kind=kind, detail=detail))
        elif not self._initialized:
            self._events.append(OdometryEvent(t_ns=t_ns, kind="initialized", detail="stereo"))
        self._initialized = True

    def _in_lens(self, uv_rect: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Rectified keypoints in the left camera: through its lens (pixels) and undistorted
        (normalised)."""
        c, n = self.rectified, len(uv_rect)
        if self.rectifier is not None:  # (a corrected pair's pixels where the stated one has them)
            uv_rect = self.rectifier.uncorrected(uv_rect)
        rect = np.column_stack(
            [(uv_rect[:, 0] - c.cx) / c.fx, (uv_rect[:, 1] - c.cy) / c.fy, np.ones(n)]
        )
        rays = rect @ self._R0  # (the rectified rays in the left camera: R0^T r)
        xy = rays[:, :2] / rays[:, 2:3]
        return (self.left.camera.project(rays) if n else np.zeros((0, 2))), xy

    def _tracked(self, frame: Frame, result: TrackResult) -> FrameFeatures:
        uv_px, xy = self._in_lens(frame.features.uv_px[result.keypoints])
        return FrameFeatures(
            t_ns=frame.t_ns, ids=np.asarray(result.points, np.int64), uv_px=uv_px, xy=xy,
            velocity_xy_s=np.zeros_like(xy),
        )  # fmt: skip

    def _record(self, kf: SlamKeyframe) -> KeyframeRecord:
        """Keyframe ``kf`` as a record (see the module)."""
        m, f = self.tracker.map, kf.frame.features
        n = len(f)
        uv_px, xy = self._in_lens(f.uv_px)
        has = kf.points >= 0
        has[has] = ~m.bad[kf.points[has]]
        ids = np.where(has, kf.points, -(NO_POINT + np.arange(n)))
        lm = np.unique(kf.points[has])
        T_W_C = self.T_O_S @ kf.T_C_W.inverse()
        return KeyframeRecord(
            index=kf.index, t_ns=kf.frame.t_ns, reset_counter=self._resets,
            T_W_B=T_W_C @ self.T_B_C.inverse(), cov_pose=_COV_POSE, camera=self._names[0],
            image=self._images.get(kf.index), ids=ids,
            uv_px=uv_px, xy=xy,
            descriptors=f.descriptors, described=np.ones(n, bool), landmark_ids=lm,
            landmarks_W=self.T_O_S @ m.X_W[lm] if len(lm) else np.zeros((0, 3)),
        )  # fmt: skip

    def _time(self, stage: str, seconds: float) -> None:
        self._seconds[stage] = self._seconds.get(stage, 0.0) + seconds
        self._calls[stage] += 1


def _given_intrinsics(
    rectified: StereoCamera, intrinsics: Sequence[float], *, stereo: bool
) -> StereoCamera:
    """The rectified camera with ``intrinsics`` (fx, fy, cx, cy) instead of its own: a stereo
    rig's only, finite, and within 5 % (focal lengths) and 5 % of the width (centre) of the
    rectification's, as an estimate of the same camera's error is."""
    if not stereo:
        raise SlamError("intrinsics: given for a stereo rig's rectified camera; this rig is RGB-D")
    vals = tuple(float(v) for v in intrinsics)
    if len(vals) != 4 or not all(math.isfinite(v) for v in vals):
        raise SlamError(f"intrinsics: four finite numbers (fx, fy, cx, cy), got {vals}")
    fx, fy, cx, cy = vals
    r = rectified
    for name, a, b, scale in (("fx", fx, r.fx, r.fx), ("fy", fy, r.fy, r.fy),
                              ("cx", cx, r.cx, 2 * r.cx), ("cy", cy, r.cy, 2 * r.cy)):  # fmt: skip
        if abs(a - b) > 0.05 * scale:
            raise SlamError(
                f"intrinsics: {name} {a:.6g} px is more than 5 % off this rig's rectified "
                f"camera ({b:.6g} px): not an estimate for this camera"
            )
    return StereoCamera(fx=fx, fy=fy, cx=cx, cy=cy, baseline_m=r.baseline_m)


def _check_same_camera(camera: StereoCamera, made_with: StereoCamera | None) -> None:
    """A map is only good with the camera it was measured in: focal lengths, centre and
    baseline within 2 % (a recalibration of the same camera passes, as loop closure's maps)."""
    if made_with is None:
        raise SlamError("a loaded map needs the camera it was made with (map_camera)")
    if (why := camera.mismatch(made_with, 0.02)) is not None:
        raise SlamError(f"the map was made with another camera ({why})")
