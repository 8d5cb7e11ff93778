"""Scenes: boxes and tessellation, the plan's checks, the built-in worlds (closed, clear of the
path, seeded, texture-poor on request) and markers placed as textured quads."""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import pytest

from quadnav.errors import SimError
from quadnav.geometry.camera import PinholeCamera, thesis_camera
from quadnav.geometry.rotations import Pose
from quadnav.sim.render import Renderer, look_at
from quadnav.sim.scene import WORLDS, Scene, Texture, WorldPlan, add_markers, box, tessellate

PLANS = {
    "room": WorldPlan(flight_min_m=(-1.5, -1.5, 0.4), flight_max_m=(1.5, 1.5, 1.8), seed=3),
    "hall": WorldPlan(flight_min_m=(-4, -3, 0.5), flight_max_m=(4, 3, 3.0), seed=3),
    "yard": WorldPlan(flight_min_m=(-4, -4, 1.0), flight_max_m=(4, 4, 4.0), seed=3),
    "marker_floor": WorldPlan(flight_min_m=(-1, -1, 0.5), flight_max_m=(1, 1, 2.0), seed=3),
    "aliased": WorldPlan(flight_min_m=(-1.5, -1.5, 0.4), flight_max_m=(1.5, 1.5, 1.8), seed=3),
}
WIDE = PinholeCamera(np.array([[40.0, 0, 39.5], [0, 40.0, 29.5], [0, 0, 1]]), np.zeros(0), 80, 60)


def _tex() -> Texture:
    return Texture(np.arange(64, dtype=np.uint8).reshape(8, 8) * 3, 0.1)


def test_box_faces_face_out_or_in() -> None:
    lo, hi = np.array([0.0, 1.0, 2.0]), np.array([1.0, 3.0, 2.5])
    for inward, sign in ((False, 1.0), (True, -1.0)):
        faces = box(lo, hi, _tex(), inward=inward)
        assert len(faces) == 6
        for f in faces:
            out = f.points_W.mean(axis=0) - 0.5 * (lo + hi)
            assert sign * (f.normal_W @ out) > 0
            side = abs(f.normal_W[2]) < 0.5
            assert not side or f.v_W[2] == pytest.approx(-1.0)  # upright textures


def test_tessellation_keeps_the_area_and_the_mapping_one_tile_per_cell() -> None:
    (floor,) = [f for f in box([0, 0, 0], [2.5, 1.7, 1], _tex()) if f.normal_W[2] > 0.5]
    cells = tessellate(floor, 0.5)

    def area(p: np.ndarray) -> float:
        return float(0.5 * np.linalg.norm(np.cross(p[1:-1] - p[0], p[2:] - p[0]).sum(axis=0)))

    assert sum(area(c.points_W) for c in cells) == pytest.approx(area(floor.points_W))
    assert len(cells) >= 15
    for c in cells:
        assert np.array_equal(c.origin_W, floor.origin_W) and np.array_equal(c.u_W, floor.u_W)
        for axis in (c.u_W, c.v_W):
            t = (c.points_W - c.origin_W) @ axis / 0.8  # the tile: 8 texels of 0.1 m
            assert np.floor(t.min() + 1e-9) >= np.ceil(t.max() - 1e-9) - 1
            assert np.ptp(t) <= 0.5 / 0.8 + 1e-9


def test_world_plan_rejects_what_it_cannot_build() -> None:
    with pytest.raises(SimError, match="flight_max_m"):
        WorldPlan(flight_min_m=(0, 0, 0), flight_max_m=(1, -1, 1))
    with pytest.raises(SimError, match="texture_poor"):
        WorldPlan(flight_min_m=(0, 0, 0), flight_max_m=(1, 1, 1), texture_poor=1.5)
    with pytest.raises(SimError, match="finite"):
        WorldPlan(flight_min_m=(0, 0, float("nan")), flight_max_m=(1, 1, 1))
    with pytest.raises(SimError, match="path_W"):
        WorldPlan(flight_min_m=(0, 0, 0), flight_max_m=(1, 1, 1), path_W=np.full((3, 3), np.inf))


def _views(plan: WorldPlan, n: int) -> list[Pose]:
    rng = np.random.default_rng(11)
    lo, hi = np.asarray(plan.flight_min_m), np.asarray(plan.flight_max_m)
    out = []
    for k in range(n):
        eye = rng.uniform(lo, hi)
        yaw, pitch = rng.uniform(-np.pi, np.pi), [-1.4, -0.6, 0.0, 0.5, 1.2][k % 5]
        d = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)])
        out.append(look_at(eye, eye + d))
    return out


@pytest.mark.parametrize("name", sorted(WORLDS))
def test_every_world_is_closed_around_its_flight_box(name: str) -> None:
    plan = PLANS[name]
    scene = WORLDS[name](plan)
    r = Renderer(scene, WIDE)
    u, v = np.meshgrid(np.arange(WIDE.width), np.arange(WIDE.height))
    rays_C = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(WIDE.K).T
    for T in _views(plan, 10):
        f = r.render(T)
        if name == "yard":  # the sky: empty and bright; everything below the horizon is hit
            down = (rays_C @ T.R_A_B.as_matrix().T)[..., 2] < -0.1 * np.linalg.norm(rays_C, axis=-1)
            assert np.isfinite(f.depth_m[down]).all()
            assert (f.image[~np.isfinite(f.depth_m)] == 235).all()
        else:
            assert np.isfinite(f.depth_m).all(), f"{name}: holes at {T.p_A_B}"
        assert f.image[np.isfinite(f.depth_m)].std() > 10  # textured, not flat


def _aabb_distance(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    d = np.maximum(np.maximum(lo - points, points - hi), 0.0)
    return float(np.sqrt((d**2).sum(axis=1)).min())


@pytest.mark.parametrize("name", ["room", "hall", "yard"])
def test_obstacles_keep_their_clearance_from_the_path(name: str) -> None:
    base = PLANS[name]
    lo, hi = np.asarray(base.flight_min_m), np.asarray(base.flight_max_m)
    c, r = 0.5 * (lo + hi), 0.4 * (hi - lo)
    s = np.linspace(0, 2 * np.pi, 40)
    path = np.column_stack([c[0] + r[0] * np.cos(s), c[1] + r[1] * np.sin(s), c[2] + 0 * s])
    plan = WorldPlan(
        flight_min_m=base.flight_min_m, flight_max_m=base.flight_max_m, seed=5, path_W=path
    )
    t = np.linspace(0, 1, 20)[:, None]
    dense = np.concatenate([a + t * (b - a) for a, b in itertools.pairwise(path)])
    inside = 0
    for p in WORLDS[name](plan).polygons:
        if p.name.startswith("obstacle:"):
            p_lo, p_hi = p.points_W.min(axis=0), p.points_W.max(axis=0)
            assert _aabb_distance(dense, p_lo, p_hi) >= 0.5 - 1e-6, p.name
            inside += bool((p_lo < hi).all() and (p_hi > lo).all())
    if name != "yard":  # with a path, furniture may stand in the flight box (around the path)
        assert inside > 0
    # without a path they keep out of the flight box and its clearance
    for p in WORLDS[name](base).polygons:
        if p.name.startswith("obstacle:"):
            p_lo, p_hi = p.points_W.min(axis=0), p.points_W.max(axis=0)
            assert ((p_hi <= lo - 0.5 + 1e-6) | (p_lo >= hi + 0.5 - 1e-6)).any(), p.name


def test_worlds_are_seeded() -> None:
    plan = PLANS["room"]
    a, b = WORLDS["room"](plan), WORLDS["room"](plan)
    other = WorldPlan(flight_min_m=plan.flight_min_m, flight_max_m=plan.flight_max_m, seed=4)
    c = WORLDS["room"](other)
    pts = lambda s: np.concatenate([p.points_W for p in s.polygons])  # noqa: E731
    assert np.array_equal(pts(a), pts(b))
    assert len(c.polygons) != len(a.polygons) or not np.array_equal(pts(a), pts(c))


def test_texture_poor_makes_surfaces_flat() -> None:
    base = PLANS["room"]
    for poor, flat_share in ((0.0, (0.0, 0.1)), (1.0, (0.99, 1.0))):
        plan = WorldPlan(
            flight_min_m=base.flight_min_m, flight_max_m=base.flight_max_m, texture_poor=poor
        )
        polys = [p for p in WORLDS["room"](plan).polygons if p.name != "poster"]
        flat = np.mean([p.texture.image.std() < 5 for p in polys])
        assert flat_share[0] <= flat <= flat_share[1]


def test_markers_on_the_floor_are_found_where_they_lie() -> None:
    cam = thesis_camera()
    scene = WORLDS["marker_floor"](PLANS["marker_floor"])
    T = look_at(np.array([0.1, -0.1, 2.0]), np.array([0.1, 0.05, 0.0]), np.array([0, 1, 0]))
    img = Renderer(scene, cam).render(T).image
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_250)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_CONTOUR  # lines fitted to the edges
    corners, ids, _ = cv2.aruco.ArucoDetector(d, params).detectMarkers(img)
    assert ids is not None and len(ids) >= 6
    # the layout: every 0.6 m from the flight box's corner less 0.6 m, 6 per row here
    xs = np.arange(-1.6, 1.6 + 1e-9, 0.6)
    half = 0.2335 / 2
    for marker_id, c in zip(ids.ravel(), corners, strict=True):
        x, y = xs[marker_id % len(xs)], xs[marker_id // len(xs)]
        # ArUco's corner order: top-left, top-right, bottom-right, bottom-left of the print
        M = np.array([[-half, half, 0], [half, half, 0], [half, -half, 0], [-half, -half, 0]])
        expected = cam.project(T.inverse() @ (M + [x, y, 0.0]))
        # the detector's corners (straight edges fitted in a distorted image, near its border
        # too) are within a pixel or so; their centre is exact
        found = c.reshape(4, 2)
        assert np.abs(found.mean(axis=0) - expected.mean(axis=0)).max() < 0.3
        assert np.abs(found - expected).max() < 1.5  # and a turned marker is off by its side


def test_markers_can_hang_on_a_wall_of_any_world() -> None:
    scene = WORLDS["hall"](PLANS["hall"])
    # on the plane x = 2 facing -x (towards the camera): marker z = -x, x = -y... turned
    R = Pose.from_matrix(np.array([[0, 0, -1, 0], [-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1.0]]))
    wall = Scene((*scene.polygons, *box([2.0, -1, 0.5], [2.3, 1, 2.5], _tex())), "hall")
    T_W_M = Pose(R.R_A_B, np.array([2.0, 0.0, 1.5]))
    scene = add_markers(wall, [(42, 0.3, T_W_M)])
    cam = WIDE.scaled(320, 240)
    img = Renderer(scene, cam).render(look_at(np.array([0.5, 0.0, 1.5]), T_W_M.p_A_B)).image
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_250)
    _, ids, _ = cv2.aruco.ArucoDetector(d).detectMarkers(img)
    assert ids is not None and 42 in ids.ravel()
