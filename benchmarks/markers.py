"""Per-frame time of marker detection + pose at 640x480 on one core, against bare
``cv2.aruco.ArucoDetector.detectMarkers`` (OpenCV's default parameters) on the same frames in
the same run, and frames per second of the synthetic renderer.

Frames: renders of the default flight's marker field (thesis camera, 6x6 markers of 0.2335 m,
1.5 m above the floor, the vehicle moving over it) and, when ../shared/data is present, the
thesis's own video of a ChArUco board. Prints a table and writes
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
from quadnav.geometry.rotations import Pose
from quadnav.sim.camera import RenderSettings, SyntheticCamera, marker_object
from quadnav.vision.camera import thesis_camera
from quadnav.vision.markers import CharucoSpec, get_dictionary, to_gray
from quadnav.vision.pipeline import MapBoard, MarkerMap, MarkerPipeline

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "thesis_rig"


def best_per_frame_ms(fn, frames, repeats: int = 3) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for f in frames:
            fn(f)
        best = min(best, (time.perf_counter() - t0) / len(frames) * 1e3)
    return best


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
        t_bare = best_per_frame_ms(bare.detectMarkers, fr)
        t_ours = best_per_frame_ms(pipe.process, fr)
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
