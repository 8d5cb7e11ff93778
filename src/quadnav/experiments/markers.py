"""Marker pose accuracy on synthetic renders: a marker seen from random viewpoints (distance,
off-axis angle, roll, where it falls in the image), rendered with noise by the synthetic camera,
detected and posed by the vision pipeline, compared with the truth."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose
from quadnav.sim.camera import RenderSettings, SyntheticCamera, marker_object
from quadnav.vision.markers import get_dictionary
from quadnav.vision.pipeline import MarkerMap, MarkerPipeline

__all__ = ["SyntheticMarkerStudy", "look_at", "synthetic_marker_study"]

FloatArray = NDArray[np.float64]


def look_at(eye: FloatArray, target: FloatArray, roll_rad: float = 0.0) -> Pose:
    """``T_W_C`` of a camera at ``eye`` whose optical axis (z) points at ``target``, turned by
    ``roll_rad`` about that axis."""
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    up = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = Rotation.from_matrix(np.column_stack([x, y, z])) * Rotation.from_rotvec([0, 0, roll_rad])
    return Pose(R, np.asarray(eye, float))


@dataclass(frozen=True, slots=True)
class SyntheticMarkerStudy:
    """Per view: distance (m), off-axis angle (deg), position error (m), orientation error
    (deg), NEES (6 states) of the camera pose; NaN where nothing was detected."""

    distance_m: FloatArray
    off_axis_deg: FloatArray
    position_error_m: FloatArray
    orientation_error_deg: FloatArray
    nees: FloatArray

    @property
    def detected(self) -> NDArray[np.bool_]:
        return np.isfinite(self.position_error_m)


def synthetic_marker_study(
    camera: PinholeCamera,
    *,
    n_views: int = 100,
    seed: int = 0,
    length_m: float = 0.2335,
    distance_m: tuple[float, float] = (0.5, 3.0),
    max_off_axis_deg: float = 40.0,
    settings: RenderSettings | None = None,
) -> SyntheticMarkerStudy:
    """Render ``n_views`` random views of one marker at the world origin and pose each."""
    rng = np.random.default_rng(seed)
    d = get_dictionary("DICT_4X4_250")
    scene = SyntheticCamera(
        camera,
        [marker_object(d, 7, length_m, Pose.identity())],
        settings or RenderSettings(noise_sigma=3.0, seed=seed),
    )
    pipeline = MarkerPipeline(
        camera, MarkerMap.single_marker(7, length_m, "DICT_4X4_250"), Pose.identity()
    )
    out: dict[str, list[float]] = {k: [] for k in ("d", "a", "p", "o", "n")}
    h = 0.5 * length_m
    corners = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]])
    while len(out["d"]) < n_views:
        dist = rng.uniform(*distance_m)
        off = math.radians(rng.uniform(0.0, max_off_axis_deg))
        az = rng.uniform(-math.pi, math.pi)
        normal_dir = np.array(
            [math.sin(off) * math.cos(az), math.sin(off) * math.sin(az), math.cos(off)]
        )
        # aim near the marker, so it lands anywhere in the middle of the image
        aim = np.append(rng.uniform(-0.25, 0.25, 2) * dist * 0.5, 0.0)
        T_W_C = look_at(dist * normal_dir, aim, rng.uniform(-math.pi, math.pi))
        px = camera.project(T_W_C.inverse() @ corners)
        margin = 0.03 * length_m / dist * camera.fx + 4  # the quiet zone must be in view too
        if not (
            np.all(px[:, 0] > margin)
            and np.all(px[:, 0] < camera.width - margin)
            and np.all(px[:, 1] > margin)
            and np.all(px[:, 1] < camera.height - margin)
        ):
            continue
        fp = pipeline.process(scene.render(T_W_C))
        out["d"].append(float(np.linalg.norm(T_W_C.p_A_B)))
        out["a"].append(
            math.degrees(math.acos(min(1.0, abs(float(T_W_C.R_A_B.apply([0, 0, 1.0])[2])))))
        )
        if fp.pose is None:
            for k in ("p", "o", "n"):
                out[k].append(math.nan)
            continue
        est = fp.pose.T_W_B  # the camera itself (identity mount)
        dp = T_W_C.p_A_B - est.p_A_B
        dth = (T_W_C.R_A_B * est.R_A_B.inv()).as_rotvec()  # R_true = Exp(dth) R_est
        e = np.concatenate([dp, dth])
        out["p"].append(float(np.linalg.norm(dp)))
        out["o"].append(math.degrees(float(np.linalg.norm(dth))))
        out["n"].append(float(e @ np.linalg.solve(fp.pose.cov, e)))
    return SyntheticMarkerStudy(*(np.array(out[k]) for k in ("d", "a", "p", "o", "n")))
