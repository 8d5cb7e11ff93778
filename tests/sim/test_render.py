"""The renderer: projection, occlusion and depth, anti-aliasing, near-plane clipping, effects,
bad input."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import SimError
from quadnav.geometry.camera import PinholeCamera, thesis_camera
from quadnav.geometry.rotations import Pose
from quadnav.sim.render import RenderEffects, Renderer, depth_noise, look_at
from quadnav.sim.scene import Scene, Texture, box, polygon


def _camera(w: int = 320, h: int = 240, f: float = 300.0) -> PinholeCamera:
    K = np.array([[f, 0.0, 0.5 * w - 0.3], [0.0, f, 0.5 * h + 0.2], [0.0, 0.0, 1.0]])
    return PinholeCamera(K, np.zeros(0), w, h)


def _flat(grey: int, size: int = 8, m: float = 0.05) -> Texture:
    return Texture(np.full((size, size), grey, np.uint8), m)


def _checker(n_squares: int, square_px: int, m_per_texel: float) -> Texture:
    idx = np.arange(n_squares * square_px) // square_px
    img = np.where((idx[:, None] + idx[None, :]) % 2 == 0, 40, 215).astype(np.uint8)
    return Texture(img, m_per_texel)


def _wall(x_m: float, half_m: float, tex: Texture, name: str = "wall") -> list:
    """A square at x = x_m facing -x (towards the origin), centred on the x axis."""
    h = half_m
    pts = [[x_m, h, -h], [x_m, -h, -h], [x_m, -h, h], [x_m, h, h]]
    return [polygon(pts, tex, u_dir_W=[0, -1, 0], shade=1.0, name=name)]


# --- projection -----------------------------------------------------------------------------


@pytest.mark.parametrize("height_m", [0.6, 0.9, 1.3])
@pytest.mark.parametrize("distorted", [False, True])
def test_checker_corners_land_where_the_camera_projects_them(
    distorted: bool, height_m: float
) -> None:
    cam = thesis_camera()  # radial-tangential distortion, or the same without it
    cam = cam if distorted else PinholeCamera(cam.K, np.zeros(0), cam.width, cam.height)
    tex = _checker(8, 64, 0.001)  # 0.064 m squares, a 0.512 m board
    pts = [[0, 0, 0], [0.512, 0, 0], [0.512, 0.512, 0], [0, 0.512, 0]]
    board = polygon(pts, tex, u_dir_W=[1, 0, 0], shade=1.0)  # faces +z; v = u x n = -y
    board = dataclasses.replace(board, origin_W=np.array([0.0, 0.512, 0.0]))
    T_W_C = look_at(np.array([0.35, 0.1, height_m]), np.array([0.25, 0.27, 0]), np.array([0, 1, 0]))
    frame = Renderer(Scene((board,)), cam).render(T_W_C)
    ij = np.array([(i, j) for i in range(1, 8) for j in range(1, 8)], np.float64)
    corners_W = np.column_stack([ij[:, 0] * 0.064, 0.512 - ij[:, 1] * 0.064, np.zeros(len(ij))])
    expected = cam.project(T_W_C.inverse() @ corners_W)
    start = np.round(expected).astype(np.float32).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
    found = cv2.cornerSubPix(frame.image, start, (6, 6), (-1, -1), crit).reshape(-1, 2)
    err = np.linalg.norm(found - expected, axis=1)
    assert err.max() < 0.1, f"worst corner {err.max():.3f} px off"


# --- occlusion and depth --------------------------------------------------------------------


def _rays_W(cam: PinholeCamera, T_W_C: Pose) -> np.ndarray:
    """Each pixel's ray (h, w, 3) in the world, scaled to z = 1 in the camera."""
    u, v = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    d_C = np.stack([u, v, np.ones_like(u)], -1).astype(np.float64) @ np.linalg.inv(cam.K).T
    return np.asarray(d_C @ T_W_C.R_A_B.as_matrix().T)


def _ray_depth(cam: PinholeCamera, T_W_C: Pose, n: np.ndarray, c: float) -> np.ndarray:
    """z (along the optical axis) where each pixel's ray meets the plane n . X = c."""
    return (c - n @ T_W_C.p_A_B) / (_rays_W(cam, T_W_C) @ n)  # the ray parameter is z


def test_box_in_front_of_a_wall_occludes_it_with_exact_depth() -> None:
    cam = _camera()
    wall = _wall(5.0, 6.0, _flat(40))
    cube = box([2.0, -0.4, -0.4], [2.8, 0.4, 0.4], _flat(220))
    cube = [dataclasses.replace(f, shade=1.0) for f in cube]
    # drawn wall first and box first: the z-buffer must not care
    T_W_C = Pose(Rotation.from_euler("zyx", [8, -5, 3], degrees=True), np.zeros(3)) @ look_at(
        np.zeros(3), np.array([1.0, 0, 0])
    )
    for polys in (wall + cube, cube + wall):
        f = Renderer(Scene(tuple(polys)), cam).render(T_W_C)
        z_wall = _ray_depth(cam, T_W_C, np.array([1.0, 0, 0]), 5.0)
        z_box = _ray_depth(cam, T_W_C, np.array([1.0, 0, 0]), 2.0)
        # where each ray meets the plane x = 2 of the box's front face (away from its edges)
        hit = T_W_C.p_A_B + z_box[..., None] * _rays_W(cam, T_W_C)
        inside = (np.abs(hit[..., 1]) < 0.39) & (np.abs(hit[..., 2]) < 0.39)
        outside = (np.abs(hit[..., 1]) > 0.41) | (np.abs(hit[..., 2]) > 0.41)
        assert inside.sum() > 1000 and outside.sum() > 1000
        assert np.all(f.image[inside] == 220) and np.all(f.image[outside] == 40)
        np.testing.assert_allclose(f.depth_m[inside], z_box[inside], rtol=1e-3)
        np.testing.assert_allclose(f.depth_m[outside], z_wall[outside], rtol=1e-3)


def test_camera_in_a_room_next_to_a_wall_sees_no_holes_and_exact_depth() -> None:
    cam = _camera(160, 120, 100.0)
    lo, hi = np.array([-2.0, -1.5, 0.0]), np.array([3.0, 2.0, 2.5])
    room = Scene(tuple(box(lo, hi, _flat(120), inward=True)))
    r = Renderer(room, cam)
    # 3 cm from the -y wall, looking along it and towards it: the wall runs behind the camera
    for eye, target in [
        ([0.0, -1.47, 1.2], [2.0, -1.3, 1.0]),
        ([2.97, 1.0, 0.03], [0.0, -1.4, 0.5]),
    ]:
        T = look_at(np.array(eye), np.array(target))
        f = r.render(T)
        d_W = _rays_W(cam, T)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d_W > 0, (hi - T.p_A_B) / d_W, (lo - T.p_A_B) / d_W)
        z = np.nanmin(np.where(np.isfinite(t), t, np.inf), axis=-1)
        assert np.isfinite(f.depth_m).all() and (f.depth_m > 0).all()
        np.testing.assert_allclose(f.depth_m, z, rtol=1e-3)


# --- anti-aliasing --------------------------------------------------------------------------


def test_far_fine_checker_comes_out_near_its_mean() -> None:
    cam = _camera(160, 120, 100.0)
    fine = _checker(64, 1, 0.002)  # 2 mm squares: at 6 m a pixel spans 30 of them
    scene = Scene(tuple(_wall(6.0, 2.5, fine)))
    T = look_at(np.zeros(3), np.array([1.0, 0.0, 0.0]))
    centre = (slice(45, 75), slice(65, 95))
    T = Pose(T.R_A_B * Rotation.from_euler("xz", [5, 3], degrees=True), T.p_A_B)  # no lucky phase
    mip = Renderer(scene, cam).render(T).image[centre].astype(float)
    assert abs(mip.mean() - 127.5) < 4 and mip.std() < 4
    level0 = Renderer(scene, cam, mipmaps=False).render(T).image[centre].astype(float)
    assert level0.std() > 20  # the same view without mip levels aliases


# --- effects --------------------------------------------------------------------------------


def _grey_frame(level: int = 100) -> np.ndarray:
    return np.full((120, 160), level, np.uint8)


def test_exposure_scales_the_mean_and_saturates() -> None:
    rng = np.random.default_rng(0)
    img = _grey_frame(100)
    assert RenderEffects(exposure_gain=0.5).apply(img, rng).mean() == pytest.approx(50, abs=0.5)
    assert RenderEffects(exposure_gain=3.0).apply(img, rng).max() == 255


def test_read_and_shot_noise_have_their_sigma() -> None:
    rng = np.random.default_rng(1)
    read = RenderEffects(read_noise_sigma=4.0).apply(_grey_frame(100), rng).astype(float)
    assert read.std() == pytest.approx(4.0, rel=0.05) and read.mean() == pytest.approx(100, abs=0.2)
    dark = RenderEffects(shot_noise_dn=0.5).apply(_grey_frame(20), rng).astype(float)
    bright = RenderEffects(shot_noise_dn=0.5).apply(_grey_frame(200), rng).astype(float)
    assert dark.std() == pytest.approx(np.sqrt(0.5 * 20), rel=0.1)
    assert bright.std() == pytest.approx(np.sqrt(0.5 * 200), rel=0.05)


def test_vignetting_darkens_the_corners() -> None:
    out = RenderEffects(vignetting=0.4).apply(_grey_frame(200), np.random.default_rng(0))
    assert out[60, 80] >= 199 and out[0, 0] == pytest.approx(120, abs=1)


def test_noise_is_deterministic_per_seed() -> None:
    e = RenderEffects(read_noise_sigma=3.0, shot_noise_dn=0.2)
    a = e.apply(_grey_frame(), np.random.default_rng(7))
    b = e.apply(_grey_frame(), np.random.default_rng(7))
    c = e.apply(_grey_frame(), np.random.default_rng(8))
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_motion_blur_lowers_gradient_energy_along_the_motion_only() -> None:
    cam = _camera(160, 120, 100.0)
    bars = (np.arange(512) // 32) % 2 * 80  # 0.32 m bars, ~10 px: rows plus columns
    grid = Texture((40 + bars[:, None] + bars[None, :]).astype(np.uint8), 0.01)
    scene = Scene(tuple(_wall(3.0, 3.0, grid)))
    T = look_at(np.zeros(3), np.array([1.0, 0.0, 0.0]))
    # the camera slides 20 cm sideways (image x) during the exposure: about 7 px of smear
    poses = [Pose(T.R_A_B, np.array([0.0, y, 0.0])) for y in np.linspace(-0.1, 0.1, 9)]
    r = Renderer(scene, cam)
    sharp = r.render(T).image.astype(float)
    blurred = r.render(T, blur_poses=poses).image.astype(float)
    gx = lambda im: float((np.diff(im, axis=1) ** 2).sum())  # noqa: E731
    gy = lambda im: float((np.diff(im, axis=0) ** 2).sum())  # noqa: E731
    assert gx(blurred) < 0.6 * gx(sharp)
    assert gy(blurred) > 0.9 * gy(sharp)


def test_depth_noise_grows_with_distance_and_stops_at_its_range() -> None:
    rng = np.random.default_rng(3)
    z = np.concatenate([np.full(20000, 1.0), np.full(20000, 3.0), np.full(10, 9.0)]).astype(
        np.float32
    )
    z[-1] = np.inf
    noisy = depth_noise(z, rng, sigma0_m=0.002, sigma_per_m2=0.003, max_range_m=8.0)
    assert np.std(noisy[:20000] - 1.0) == pytest.approx(0.005, rel=0.05)
    assert np.std(noisy[20000:40000] - 3.0) == pytest.approx(0.029, rel=0.05)
    assert np.isinf(noisy[40000:]).all()


# --- bad input ------------------------------------------------------------------------------


def test_bad_input_is_a_one_line_sim_error() -> None:
    cam = _camera(32, 24, 20.0)
    with pytest.raises(SimError, match="empty"):
        Renderer(Scene(()), cam)
    r = Renderer(Scene(tuple(_wall(3.0, 1.0, _flat(90)))), cam)
    T = Pose.identity()
    object.__setattr__(T, "p_A_B", np.array([np.nan, 0.0, 0.0]))
    with pytest.raises(SimError, match="not finite"):
        r.render(T)
    tex = _flat(90)
    with pytest.raises(SimError, match="at least 3 points"):
        polygon([[0, 0, 0], [1, 0, 0]], tex)
    with pytest.raises(SimError, match="zero area"):
        polygon([[0, 0, 0], [1, 0, 0], [2, 0, 0]], tex)
    with pytest.raises(SimError, match="not in one plane"):
        polygon([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.3]], tex)
    with pytest.raises(SimError, match="not convex"):
        polygon([[0, 0, 0], [2, 0, 0], [1, 0.2, 0], [1, 2, 0]], tex)
    with pytest.raises(SimError, match="read_noise_sigma"):
        RenderEffects(read_noise_sigma=-1.0)


def test_depth_through_the_lens_is_the_walls_distance_everywhere() -> None:
    cam = thesis_camera().scaled(160, 120)
    scene = Scene(tuple(_wall(2.5, 4.0, _flat(90))))
    f = Renderer(scene, cam).render(look_at(np.zeros(3), np.array([1.0, 0.0, 0.0])))
    np.testing.assert_allclose(f.depth_m, 2.5, rtol=1e-5)  # a wall square to the axis: z = x
    assert f.image.shape == (120, 160) and (f.image == 90).all()


def test_motion_blur_through_a_distorting_lens_averages_the_lens_images() -> None:
    """With a lens (the ideal image is wider than the sensor's), the blurred image has the
    sensor's size and, with every pose the same, equals the sharp one."""
    cam = thesis_camera().scaled(160, 120)
    bars = (np.arange(512) // 32) % 2 * 80
    grid = Texture((40 + bars[:, None] + bars[None, :]).astype(np.uint8), 0.01)
    r = Renderer(Scene(tuple(_wall(3.0, 3.0, grid))), cam)
    T = look_at(np.zeros(3), np.array([1.0, 0.0, 0.0]))
    sharp = r.render(T).image
    same = r.render(T, blur_poses=[T, T, T]).image
    assert same.shape == (120, 160)
    assert np.array_equal(same, sharp)
