"""Renderer speed on one core: mono frames per second at 640x480 (thesis 003's camera) and
stereo pairs per second at 752x480 (EuRoC's cam0/cam1 intrinsics, 110 mm apart; pinhole and
with EuRoC's radial-tangential distortion) in every built-in world, effects off and on (noise,
vignetting, motion blur from 3 sub-frames); and the whole-process time of a short run
(interpreter start, imports, world build, 100 room frames). Each frame: best of ``--repeats``.

Floors: >= 100 mono frames/s and >= 50 stereo pairs/s in the room and the hall, effects off.

    python benchmarks/render.py [--repeats 5] [--frames 40] [--out benchmarks/results/render.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose
from quadnav.sim.render import RenderEffects, Renderer, look_at
from quadnav.sim.scene import WORLDS, WorldPlan

PLANS = {
    "room": WorldPlan(flight_min_m=(-2, -2, 0.5), flight_max_m=(2, 2, 2.0), seed=1),
    "hall": WorldPlan(flight_min_m=(-5, -4, 0.5), flight_max_m=(5, 4, 3.0), seed=1),
    "yard": WorldPlan(flight_min_m=(-5, -5, 1.0), flight_max_m=(5, 5, 5.0), seed=1),
    "marker_floor": WorldPlan(flight_min_m=(-1.5, -1.5, 0.5), flight_max_m=(1.5, 1.5, 2), seed=1),
}
THESIS003 = PinholeCamera(
    np.array([[381.3625, 0, 320.5], [0, 381.3625, 240.5], [0, 0, 1]]), np.zeros(0), 640, 480
)
EUROC = [
    PinholeCamera(np.array([[458.654, 0, 367.215], [0, 457.296, 248.375], [0, 0, 1]]), d, 752, 480)
    for d in (np.array([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]),)
] + [
    PinholeCamera(np.array([[457.587, 0, 379.999], [0, 456.134, 255.238], [0, 0, 1]]), d, 752, 480)
    for d in (np.array([-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05]),)
]
T_C0_C1 = Pose(Rotation.identity(), np.array([0.110, 0.0, 0.0]))


def _poses(plan: WorldPlan, n: int, seed: int = 0) -> list[Pose]:
    """Cameras spread over the flight box, looking roughly level (+-30 degrees) any way."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(plan.flight_min_m), np.asarray(plan.flight_max_m)
    out = []
    for _ in range(n):
        eye = rng.uniform(lo, hi)
        yaw, pitch = rng.uniform(-np.pi, np.pi), rng.uniform(-0.5, 0.5)
        d = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)])
        out.append(look_at(eye, eye + d))
    return out


def _best(fn: Callable[[Pose], object], poses: list[Pose], repeats: int) -> float:
    """Seconds for all poses, each the best of ``repeats`` (other sessions share the CPU: the
    least disturbed run of a frame is its cost)."""
    total = 0.0
    for T in poses:
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn(T)
            times.append(time.perf_counter() - t0)
        total += min(times)
    return total


def _world_rates(name: str, frames: int, repeats: int) -> dict[str, float]:
    plan = PLANS[name]
    t0 = time.perf_counter()
    scene = WORLDS[name](plan)
    build_s = time.perf_counter() - t0
    poses = _poses(plan, frames)
    mono = Renderer(scene, THESIS003)
    pin = [Renderer(scene, PinholeCamera(c.K, np.zeros(0), c.width, c.height)) for c in EUROC]
    dist = [Renderer(scene, c) for c in EUROC]
    fast = [Renderer(scene, c, max_ideal_pixels=1.2) for c in EUROC]
    fx = RenderEffects(read_noise_sigma=2.0, shot_noise_dn=0.3, vignetting=0.2)
    rng = np.random.default_rng(0)

    def stereo(pair: list[Renderer], T: Pose) -> None:
        pair[0].render(T)
        pair[1].render(T @ T_C0_C1)

    def mono_fx(T: Pose) -> None:
        blur = [
            T @ Pose(Rotation.from_rotvec([0, 0.004 * k, 0]), [0.003 * k, 0, 0]) for k in (-1, 0, 1)
        ]
        fx.apply(mono.render(T, blur_poses=blur).image, rng)

    return {
        "build_s": build_s,
        "polygons": len(scene.polygons),
        "mono_fps": frames / _best(mono.render, poses, repeats),
        "mono_fps_effects_blur3": frames / _best(mono_fx, poses, repeats),
        "stereo_pairs_per_s_pinhole": frames / _best(lambda T: stereo(pin, T), poses, repeats),
        "stereo_pairs_per_s_euroc_distortion": frames / _best(lambda T: stereo(dist, T), poses, repeats),
        "stereo_pairs_per_s_euroc_max_ideal_1.2": frames / _best(lambda T: stereo(fast, T), poses, repeats),
    }  # fmt: skip


def _short_run() -> None:
    scene = WORLDS["room"](PLANS["room"])
    r = Renderer(scene, THESIS003)
    for T in _poses(PLANS["room"], 100):
        r.render(T)


def main() -> None:
    parser = argparse.ArgumentParser(description="renderer speed")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/render.json"))
    parser.add_argument("--short-run", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    if args.short_run:
        _short_run()
        return
    rows = {name: _world_rates(name, args.frames, args.repeats) for name in WORLDS}
    procs = []
    for _ in range(3):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, __file__, "--short-run"], check=True)
        procs.append(time.perf_counter() - t0)
    cols = [
        ("polygons", "polys", "d"),
        ("build_s", "build s", ".3f"),
        ("mono_fps", "mono fps", ".0f"),
        ("mono_fps_effects_blur3", "mono+fx+blur3", ".0f"),
        ("stereo_pairs_per_s_pinhole", "stereo pinhole", ".0f"),
        ("stereo_pairs_per_s_euroc_distortion", "stereo euroc", ".0f"),
        ("stereo_pairs_per_s_euroc_max_ideal_1.2", "euroc, ideal 1.2", ".0f"),
    ]
    print(f"{'world':<13}" + "".join(f"{h:>16}" for _, h, _ in cols))
    for name, row in rows.items():
        print(f"{name:<13}" + "".join(f"{row[k]:>16{f}}" for k, _, f in cols))
    print(
        f"whole process: 100 room frames at 640x480 incl. start-up, best of 3: {min(procs):.2f} s"
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({
        "benchmark": "render", "python": platform.python_version(), "opencv": cv2.__version__, "threads": 1,
        "frames": args.frames, "repeats": args.repeats, "worlds": rows, "short_run_process_s": min(procs),
    }, indent=2) + "\n")  # fmt: skip
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
