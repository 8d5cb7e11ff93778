"""The second camera of a stereo rig (VINS-Fusion's and ORB-SLAM3's stereo-inertial mode): the
left frame's tracked corners found in the right image by KLT (started where a point at infinity
would fall, checked forward-backward and against the epipolar line of the calibrated pair), and
the pairing of the two cameras' frames, which may arrive in either order, or one without the
other.

A rig whose two cameras cannot make a stereo pair (different lens models or image sizes, no
baseline) is refused when the odometry is made, in one line naming ``--stereo``."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import VioError, VisionError
from quadnav.messages import ImageFrame
from quadnav.odometry import FrameFeatures
from quadnav.rig import CameraSpec, Rig
from quadnav.units import s_to_ns
from quadnav.vio.config import VioConfig
from quadnav.vio.frontend import normalised
from quadnav.vision.stereo import StereoRectifier
from quadnav.vision.tracking import StereoGeometry, track_stereo

__all__ = ["PendingFrame", "StereoFrontend", "partner_camera"]

Image = NDArray[np.uint8]


def partner_camera(rig: Rig, left: str) -> CameraSpec:
    """The rig's other camera for a stereo pair with ``left``, checked that the two can be
    rectified (same lens model and size, a baseline): a :class:`VioError` naming ``--stereo``."""
    others = [c for c in rig.cameras if c.name != left]
    if not others:
        raise VioError(f"--stereo: rig {rig.name!r} has one camera ({left}); stereo needs two")
    right = others[0]
    try:
        StereoRectifier.of_cameras(rig.camera(left), right)
    except VisionError as exc:
        raise VioError(f"--stereo: {left} and {right.name} of rig {rig.name!r}: {exc}") from None
    return right


@dataclass(frozen=True, slots=True, kw_only=True)
class PendingFrame:
    """A left frame tracked and waiting for its right partner: its stamp as given (the
    camera's clock), its features, its pixels and the frame they came from."""

    t_ns: int
    features: FrameFeatures
    image: Image
    source: ImageFrame


class StereoFrontend:
    """Pairs a rig's left frames with their right partners and finds the left's corners in the
    right image (see the module)."""

    def __init__(self, rig: Rig, left: str, config: VioConfig) -> None:
        spec_l = rig.camera(left)
        spec_r = partner_camera(rig, left)
        self.left, self.right = spec_l, spec_r
        self.config = config
        self.geometry = StereoGeometry(
            left=spec_l.camera, right=spec_r.camera, T_L_R=spec_l.T_B_C.inverse() @ spec_r.T_B_C
        )
        self.tolerance_ns = s_to_ns(config.stereo_pair_tolerance_s)
        self.pending: PendingFrame | None = None
        self._rights: dict[int, Image] = {}
        self.last_right_ns: int | None = None

    def put_right(self, t_ns: int, image: Image) -> None:
        """A right frame waiting for its left (the newest few are kept)."""
        self._rights[int(t_ns)] = image
        for t in sorted(self._rights)[:-3]:
            del self._rights[t]

    def take_right(self, t_ns: int) -> Image | None:
        """The right frame within the tolerance of a left stamp, if it came (and is taken)."""
        near = [t for t in self._rights if abs(t - t_ns) <= self.tolerance_ns]
        if not near:
            return None
        best = min(near, key=lambda t: abs(t - t_ns))
        image = self._rights.pop(best)
        for t in [t for t in self._rights if t < best]:
            del self._rights[t]  # older than a paired one: their left will not come
        return image

    def pairs_with_pending(self, t_ns: int) -> bool:
        return self.pending is not None and abs(self.pending.t_ns - int(t_ns)) <= self.tolerance_ns

    def overdue(self, t_ns: int) -> bool:
        """The pending left's partner is late: the stream has moved past it (``t_ns``)."""
        return self.pending is not None and int(t_ns) > self.pending.t_ns + self.tolerance_ns

    def match(self, frame: FrameFeatures, left: Image, right: Image) -> FrameFeatures:
        """``frame`` with its corners found in the right image (``stereo_ids``, ``stereo_xy``)."""
        if len(frame.ids) == 0:
            return frame
        try:
            m = track_stereo(
                left, right, config=self.config.tracker, left_px=np.asarray(frame.uv_px),
                geometry=self.geometry, max_error_px=self.config.stereo_max_epipolar_px,
            )  # fmt: skip
        except VisionError:  # a right image of another size, say: the frame goes on as mono
            return frame
        cam = self.right.camera
        xy = normalised(cam, cam.undistort_pixels(m.right_px)) if len(m) else np.zeros((0, 2))
        return dataclasses.replace(
            frame, stereo_ids=np.asarray(frame.ids)[m.index], stereo_xy=np.asarray(xy, np.float64)
        )
