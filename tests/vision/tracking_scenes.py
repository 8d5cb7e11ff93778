"""Synthetic image pairs with a known motion for the feature tracker's tests: smooth random texture
seen through a homography, and a two-plane scene (a near plane over a far one) seen from two
camera poses, with the image motion of every pixel known."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import cv2
import numpy as np
from numpy.typing import NDArray

Image = NDArray[np.uint8]
K = np.array([[400.0, 0.0, 320.0], [0.0, 400.0, 240.0], [0.0, 0.0, 1.0]])
W, H = 640, 480
#: Frame 0 sits this far inside the texture canvas, so motion brings texture, not borders.
MARGIN = 160


def texture(h: int, w: int, rng: np.random.Generator, sigma_px: float = 1.5) -> Image:
    """Octaves of Gaussian-blurred white noise (blur ``sigma_px`` and 3, 9, 27 times it), like a
    natural image's spectrum: corners at every scale, so the coarse pyramid levels KLT starts
    from have texture too; band-limited, so warping it is exact to well under 0.1 px. A coarse
    octave is made at 1/3**k of the size and enlarged (the same spectrum, far fewer samples)."""
    t = np.zeros((h, w), np.float32)
    for k in range(4):
        f = 3**k
        small = rng.normal(size=(h // f + 4, w // f + 4)).astype(np.float32)
        octave = cv2.GaussianBlur(small, (0, 0), sigma_px)
        if f > 1:
            octave = cv2.resize(octave, ((w // f + 4) * f, (h // f + 4) * f), cv2.INTER_CUBIC)
        octave = octave[2 * f : 2 * f + h, 2 * f : 2 * f + w]
        t += octave / octave.std()
    t = (t - t.mean()) / t.std()
    return np.clip(128 + 45 * t, 0, 255).astype(np.uint8)


def canvas(rng: np.random.Generator) -> Image:
    """A texture canvas around frame 0."""
    return texture(H + 2 * MARGIN, W + 2 * MARGIN, rng)


def view(tex: Image, D: NDArray[np.float64]) -> Image:
    """Frame 1 of a canvas whose frame 0 is its centre, when frame-0 pixel x moves to D x."""
    C = np.array([[1.0, 0.0, MARGIN], [0.0, 1.0, MARGIN], [0.0, 0.0, 1.0]])
    M = C @ np.linalg.inv(D)  # frame-1 pixel -> canvas pixel
    return cv2.warpPerspective(tex, M, (W, H), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP)


def apply(D: NDArray[np.float64], px: NDArray[np.float64]) -> NDArray[np.float64]:
    return cv2.perspectiveTransform(px.reshape(-1, 1, 2), D).reshape(-1, 2)


@dataclass(frozen=True)
class TwoPlanes:
    """A near plane (depth 2 m) over the left of the image, a far one (6 m) behind, and the
    camera moved by a rotation and a 10 cm translation: frame-0 pixels move by ``D_near`` or
    ``D_far`` (plane-induced homographies), a parallax of about 13 px between them."""

    frame0: Image
    frame1: Image
    D_near: NDArray[np.float64]
    D_far: NDArray[np.float64]
    near_x_px: float  # frame-0 pixels with x below this lie on the near plane

    def truth(self, px0: NDArray[np.float64]) -> NDArray[np.float64]:
        near = px0[:, 0] < self.near_x_px
        return np.where(near[:, None], apply(self.D_near, px0), apply(self.D_far, px0))


def plane_homography(
    R: NDArray[np.float64], t: NDArray[np.float64], depth_m: float
) -> NDArray[np.float64]:
    """Frame-0 pixel -> frame-1 pixel for the fronto-parallel plane z = depth (X1 = R X0 + t)."""
    n = np.array([0.0, 0.0, 1.0])
    out: NDArray[np.float64] = K @ (R + np.outer(t, n) / depth_m) @ np.linalg.inv(K)
    return out


@cache
def two_planes(seed: int, near_x_px: float = 300.0, *, stereo: bool = False) -> TwoPlanes:
    """The scene of seed ``seed`` (made once per test session: the tests only read it); with
    ``stereo`` frame 1 is the right image of a rectified pair with EuRoC's 11 cm baseline (near
    plane disparity 22 px, far 7.3 px)."""
    rng = np.random.default_rng(seed)
    a = 0.0 if stereo else np.deg2rad(1.0)
    R = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    t = np.array([-0.11, 0.0, 0.0]) if stereo else np.array([0.10, 0.03, 0.05])
    D_near, D_far = plane_homography(R, t, 2.0), plane_homography(R, t, 6.0)
    near_tex, far_tex = canvas(rng), canvas(rng)
    ident = np.eye(3)
    near0, far0 = view(near_tex, ident), view(far_tex, ident)
    xs = np.arange(W)[None, :].repeat(H, axis=0)
    frame0 = np.where(xs < near_x_px, near0, far0).astype(np.uint8)
    # frame 1: the near plane wherever its warped region lands, the far plane elsewhere
    src = np.stack(np.meshgrid(np.arange(W), np.arange(H)), axis=-1).reshape(-1, 2).astype(float)
    back = apply(np.linalg.inv(D_near), src)[:, 0].reshape(H, W)
    frame1 = np.where(back < near_x_px, view(near_tex, D_near), view(far_tex, D_far))
    return TwoPlanes(frame0, frame1.astype(np.uint8), D_near, D_far, near_x_px)
