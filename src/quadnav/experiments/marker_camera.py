"""Vision in the loop: a downward camera over a field of markers, rendered by the synthetic
camera, detected and posed by the marker pipeline, delivered as a :class:`PoseSample` with the
pose's own covariance (thesis 000's marker system, without the pose shortcut)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.random import Generator

from quadnav.geometry.camera import PinholeCamera, thesis_camera
from quadnav.geometry.rotations import Pose
from quadnav.messages import PoseSample, VehicleState
from quadnav.sim.camera import RenderSettings, SyntheticCamera, marker_object
from quadnav.sim.sensors import Ticker
from quadnav.vision.markers import get_dictionary
from quadnav.vision.pipeline import FramePose, MapMarker, MarkerMap, MarkerPipeline
from quadnav.vision.pose import mount_pose

__all__ = ["MarkerCameraSensor", "marker_field"]


def marker_field(
    n: int, spacing_m: float, length_m: float, origin_m: tuple[float, float] = (0.0, 0.0)
) -> list[MapMarker]:
    """``n x n`` markers (ids 0...) lying on the floor, face up, ``spacing_m`` apart, the first
    at ``origin_m``."""
    out = []
    for k in range(n * n):
        i, j = k % n, k // n
        p = np.array([origin_m[0] + i * spacing_m, origin_m[1] + j * spacing_m, 0.0])
        out.append(MapMarker(k, length_m, Pose(Pose.identity().R_A_B, p)))
    return out


@dataclass
class MarkerCameraSensor:
    """Renders what the camera at ``T_W_B T_B_C`` sees every ``period_ns`` and returns the
    vehicle pose the pipeline finds, or nothing (dropouts: :class:`~quadnav.sim.channels.Dropouts`)."""

    period_ns: int
    markers: list[MapMarker]
    T_B_C: Pose
    camera: PinholeCamera | None = None
    noise_sigma: float = 2.0
    exposure_s: float = 0.004
    seed: int = 0
    #: The pipeline's covariance is the reprojection noise's alone: close to the markers it falls
    #: below a millimetre, while exposure and timing errors do not. A floor, as PX4's
    #: EKF2_EVP_NOISE is the least noise it takes an external pose to have.
    min_sigma_m: float = 0.0

    def __post_init__(self) -> None:
        self.camera = self.camera or thesis_camera()
        d = get_dictionary("DICT_4X4_250")
        objects = [marker_object(d, m.id, m.length_m, m.T_W_M) for m in self.markers]
        self.scene = SyntheticCamera(
            self.camera,
            objects,
            RenderSettings(
                noise_sigma=self.noise_sigma, blur_exposure_s=self.exposure_s, seed=self.seed
            ),
        )
        mmap = MarkerMap("DICT_4X4_250", {m.id: m for m in self.markers})
        self.pipeline = MarkerPipeline(self.camera, mmap, self.T_B_C)
        self._ticker = Ticker(self.period_ns)
        self.frames = 0
        self.poses = 0
        self.last: FramePose | None = None

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> PoseSample | None:
        del rng  # the image noise has its own generator
        if not self._ticker.due(t_ns):
            return None
        assert self.camera is not None
        T_W_B = Pose.from_quat_xyzw(truth.q_W_B_xyzw, truth.p_W_B)
        T_W_C = T_W_B @ self.T_B_C
        # image motion for the blur: the scene's velocity across the view at the floor's depth
        depth = max(float(T_W_C.p_A_B[2]), 0.1)
        v_C = T_W_C.R_A_B.apply(np.array(truth.v_W_B), inverse=True)
        w_C = self.T_B_C.R_A_B.apply(np.array(truth.w_B), inverse=True)
        vx = self.camera.fx * (-v_C[0] / depth - w_C[1])
        vy = self.camera.fy * (-v_C[1] / depth + w_C[0])
        img = self.scene.render(T_W_C, velocity_px_s=(vx, vy))
        fp = self.pipeline.process(img, t_ns)
        self.frames += 1
        self.last = fp
        if fp.pose is None:
            return None
        self.poses += 1
        cov = fp.pose.cov.copy()
        cov[0:3, 0:3] += np.eye(3) * self.min_sigma_m**2
        return PoseSample(
            t_ns=t_ns,
            p_W_B=fp.pose.T_W_B.p_A_B,
            q_W_B_xyzw=fp.pose.T_W_B.R_A_B.as_quat(),
            sigma_pos_m=math.sqrt(max(float(np.max(np.linalg.eigvalsh(cov[0:3, 0:3]))), 1e-12)),
            sigma_yaw_rad=math.sqrt(max(float(cov[5, 5]), 1e-12)),
            cov_p_m2=0.5 * (cov[0:3, 0:3] + cov[0:3, 0:3].T) + np.eye(3) * 1e-10,
        )


def thesis_mount(xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Pose:
    """The thesis's camera: looking down, turned 180 degrees about the vertical."""
    return mount_pose((180.0, 0.0, 180.0), xyz_m)
