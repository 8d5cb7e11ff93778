"""The equidistant (fisheye) model beside OpenCV's radial-tangential one."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quadnav.errors import GeometryError
from quadnav.geometry.camera import PinholeCamera

# TUM-VI's cam0 (its camchain: pinhole-equi, 512x512).
K_TUMVI = np.array([[190.978, 0.0, 254.932], [0.0, 190.973, 256.897], [0.0, 0.0, 1.0]])
D_TUMVI = [0.003482389, 0.000715034, -0.002053236, 0.000202936]


def _equidistant_by_hand(cam: PinholeCamera, p: np.ndarray) -> np.ndarray:
    """Kannala-Brandt: r(theta) = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)."""
    k1, k2, k3, k4 = cam.dist
    out = []
    for x, y, z in p:
        a, b = x / z, y / z
        r = math.hypot(a, b)
        th = math.atan(r)
        thd = th * (1 + k1 * th**2 + k2 * th**4 + k3 * th**6 + k4 * th**8)
        s = thd / r if r > 1e-12 else 1.0
        out.append([cam.K[0, 0] * a * s + cam.K[0, 2], cam.K[1, 1] * b * s + cam.K[1, 2]])
    return np.array(out)


def test_equidistant_projection_is_kannala_brandt_and_inverts() -> None:
    cam = PinholeCamera(K_TUMVI, np.array(D_TUMVI), 512, 512, "equidistant")
    rng = np.random.default_rng(3)
    p = rng.uniform([-2.0, -2.0, 0.4], [2.0, 2.0, 3.0], (200, 3))
    px = cam.project(p)
    assert np.allclose(px, _equidistant_by_hand(cam, p), atol=1e-6)
    ideal = p[:, :2] / p[:, 2:] * [K_TUMVI[0, 0], K_TUMVI[1, 1]] + K_TUMVI[:2, 2]
    assert np.allclose(cam.undistort_pixels(px), ideal, atol=1e-6)
    # and it is not the radial-tangential model with the same numbers
    radtan = PinholeCamera(K_TUMVI, np.array(D_TUMVI), 512, 512)
    assert np.abs(radtan.project(p) - px).max() > 5.0


def test_scaling_keeps_the_model() -> None:
    cam = PinholeCamera(K_TUMVI, np.array(D_TUMVI), 512, 512, "equidistant")
    assert cam.scaled(256, 256).model == "equidistant"


def test_bad_models_are_refused() -> None:
    with pytest.raises(GeometryError, match="takes 4 coefficients"):
        PinholeCamera(K_TUMVI, np.zeros(5), 512, 512, "equidistant")
    with pytest.raises(GeometryError, match="must be one of radtan, equidistant"):
        PinholeCamera(K_TUMVI, np.zeros(4), 512, 512, "fov")  # type: ignore[arg-type]


def test_radial_tangential_undistortion_inverts_a_strong_lens_to_its_corners() -> None:
    """EuRoC's cam0 (k1 = -0.28): OpenCV's default of 5 iterations leaves 0.3 px at the
    corners, the same bias in every frame; the camera's undistortion must invert projection."""
    K = np.array([[458.654, 0.0, 367.215], [0.0, 457.296, 248.375], [0.0, 0.0, 1.0]])
    cam = PinholeCamera(
        K, np.array([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]), 752, 480
    )
    rng = np.random.default_rng(5)
    # bearings whose pixels fill the image, corners included
    p = np.column_stack(
        [rng.uniform(-0.95, 0.95, 400), rng.uniform(-0.62, 0.62, 400), np.ones(400)]
    )
    px = cam.project(p)
    inside = (px[:, 0] >= 0) & (px[:, 0] < 752) & (px[:, 1] >= 0) & (px[:, 1] < 480)
    assert inside.sum() > 300
    ideal = p[:, :2] * [K[0, 0], K[1, 1]] + K[:2, 2]
    err = np.linalg.norm(cam.undistort_pixels(px[inside]) - ideal[inside], axis=1)
    assert err.max() < 1e-4
