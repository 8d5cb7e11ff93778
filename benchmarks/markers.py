"""Per-frame time of marker detection + pose at 640x480 on one core, against bare
``cv2.aruco.ArucoDetector.detectMarkers`` (OpenCV's default parameters) on the same frames in
the same run, and frames per second of the synthetic renderer.

Frames: renders of the default flight's marker field (thesis camera, 6x6 markers of 0.2335 m,
1.5 m above the floor, the vehicle moving over it); renders of the thesis's two ChArUco boards,
12x17 (0.066 m squares) and the large 16x23 (0.05 m squares), flown over at 0.2 to 0.7 m (the
thesis video's heights and above, up to most of the board in view); and, when ../shared/data
is present, the thesis's own video of the 12x17 board. Prints a table and writes
``benchmarks/results/markers.json``.

    python benchmarks/markers.py [--frames 300]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.experiments.marker_camera import marker_field, thesis_mount
from quadnav.geometry.camera import thesis_camera
from quadnav.geometry.rotations import Pose
from quadnav.sim.camera import RenderSettings, SyntheticCamera, board_object, marker_object
from quadnav.vision.markers import CharucoSpec, CharucoTarget, get_dictionary, to_gray
from quadnav.vision.pipeline import MapBoard, MarkerMap, MarkerPipeline

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "thesis_rig"


def best_per_frame_ms(fns, frames, repeats: int = 5) -> list[float]:
    """Best of ``repeats`` of each function's time per frame, the functions taking turns
    so that a busy spell of the machine falls on all of them alike."""
    best = [float("inf")] * len(fns)
    for _ in range(repeats):
        for k, fn in enumerate(fns):
            t0 = time.perf_counter()
            for f in frames:
                fn(f)
            best[k] = min(best[k], (time.perf_counter() - t0) / len(frames) * 1e3)
    return best


def board_frames(spec: CharucoSpec, n: int, seed: int = 0) -> list[np.ndarray]:
    """Renders of the board on the floor seen by the thesis mount from 0.2 to 0.7 m, moving
    across it and turning."""
    w_m, h_m = spec.squares_x * spec.square_m, spec.squares_y * spec.square_m
    board = CharucoTarget(spec).board
    scene = SyntheticCamera(thesis_camera(), [board_object(board, (w_m, h_m), Pose.identity(), px_per_m=2500)],
                            RenderSettings(noise_sigma=2.0, seed=seed))  # fmt: skip
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(n):
        s = k / max(n - 1, 1)
        p = np.array([w_m * (0.3 + 0.4 * s), h_m * (0.3 + 0.4 * s), 0.2 + 0.5 * s * s])
        R = Rotation.from_euler("ZYX", [3.0 * s + rng.normal(0, 0.1), rng.normal(0, 0.05), rng.normal(0, 0.05)])  # fmt: skip
        frames.append(scene.render(Pose(R, p + rng.normal(0, 0.01, 3)) @ thesis_mount()))
    return frames


def main() -> None:
    parser = argparse.ArgumentParser(description="marker pipeline speed")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/markers.json"))
    args = parser.parse_args()
    cv2.setNumThreads(1)  # one core, as the issue asks
    cam = thesis_camera()
    field = marker_field(6, 0.6, 0.2335, (-0.6, -0.6))
    d = get_dictionary("DICT_4X4_250")
    scene = SyntheticCamera(cam, [marker_object(d, m.id, m.length_m, m.T_W_M) for m in field], RenderSettings(noise_sigma=2.0))  # fmt: skip
    rng = np.random.default_rng(0)
    poses = []
    for k in range(args.frames):
        s = k / max(args.frames - 1, 1)
        p = np.array([2.0 * s, 2.0 * s * (1 - s) * 2, 1.5]) + rng.normal(0, 0.02, 3)
        R = Rotation.from_euler(
            "ZYX", [rng.uniform(-0.3, 0.3), rng.normal(0, 0.05), rng.normal(0, 0.05)]
        )
        poses.append(Pose(R, p) @ thesis_mount())
    t0 = time.perf_counter()
    frames = [scene.render(T) for T in poses]
    render_fps = len(frames) / (time.perf_counter() - t0)
    results: dict[str, dict[str, float]] = {}
    sets = {"synthetic marker field": (frames, MarkerMap("DICT_4X4_250", {m.id: m for m in field}))}
    for spec in (CharucoSpec(12, 17, 0.066, 0.0397, 2), CharucoSpec(16, 23, 0.05, 0.03, 2)):
        n_board = max(args.frames // 3, 10)
        name = f"rendered ChArUco {spec.squares_x}x{spec.squares_y}"
        sets[name] = (board_frames(spec, n_board), MarkerMap(2, boards=[MapBoard(spec, Pose.identity())]))  # fmt: skip
    video = DATA / "board12_17.mp4"
    if video.exists():
        cap = cv2.VideoCapture(str(video))
        vf = []
        while len(vf) < args.frames:
            ok, img = cap.read()
            if not ok:
                break
            vf.append(to_gray(img))
        board = MarkerMap(
            2, boards=[MapBoard(CharucoSpec(12, 17, 0.066, 0.0397, 2), Pose.identity())]
        )
        sets["thesis video (ChArUco 12x17)"] = (vf, board)
    for name, (fr, mmap) in sets.items():
        bare = cv2.aruco.ArucoDetector(get_dictionary(mmap.dictionary))
        pipe = MarkerPipeline(cam, mmap, thesis_mount())
        t_bare, t_ours = best_per_frame_ms([bare.detectMarkers, pipe.process], fr)
        n_pose = sum(pipe.process(f).pose is not None for f in fr)
        results[name] = {"frames": len(fr), "bare_detect_ms": t_bare, "pipeline_ms": t_ours, "ratio": t_ours / t_bare, "frames_with_pose": n_pose}  # fmt: skip
    print(
        f"{'frames':<32} {'n':>5} {'bare detect ms':>15} {'detect+pose ms':>15} {'ratio':>7} {'with pose':>10}"
    )
    for name, r in results.items():
        print(
            f"{name:<32} {r['frames']:>5} {r['bare_detect_ms']:>15.2f} {r['pipeline_ms']:>15.2f} {r['ratio']:>7.2f} {r['frames_with_pose']:>10}"
        )
    print(
        f"synthetic renderer: {render_fps:.0f} frames per second (640x480, 36 markers, distortion, noise)"
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"benchmark": "markers", "python": platform.python_version(), "opencv": cv2.__version__,
                                    "render_fps": render_fps, "sets": results}, indent=2) + "\n")  # fmt: skip
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
