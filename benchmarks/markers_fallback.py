"""The ChArUco board's marker fallback (issue 21, item 3): jitter and the fraction of frames with
a pose, with the fallback as configured and without it, on

- renders of a 5x7 ChArUco board (DICT_6X6_250, 0.0475 m squares, as the thesis's third board)
  seen by the thesis camera and mount moving and turning above it, with its left half covered
  by a grey sheet (0.25 to 0.5 m up), or all of it but one marker (0.3 to 0.9 m up):
  sequences with known truth (position error against it too);
- the thesis's own video of the 12x17 board, when ../shared/data is present.

Jitter is what ``quadnav markers`` reports (stats.json ``jitter_rms_mm``: the second difference of
consecutive positions over sqrt 6); "step" is the RMS and the largest frame-to-frame position
change. Prints a table and writes ``benchmarks/results/markers_fallback.json``.

    python benchmarks/markers_fallback.py [--frames 400] [--video-frames 1086 (0: no video)]
"""

from __future__ import annotations

import argparse
import csv
import json
import tempfile
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.experiments.marker_camera import thesis_mount
from quadnav.experiments.markers_run import run_markers
from quadnav.geometry.camera import thesis_camera
from quadnav.geometry.rotations import Pose
from quadnav.io.opencv_yaml import write_camera_yaml
from quadnav.sim.camera import PlanarObject, RenderSettings, SyntheticCamera, board_object
from quadnav.vision.config import MarkersConfig
from quadnav.vision.markers import CharucoSpec, CharucoTarget

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "thesis_rig"
SPEC = CharucoSpec(5, 7, 0.0475, 0.0285, "DICT_6X6_250")


def cover(x0_m: float, x1_m: float, y0_m: float, y1_m: float) -> PlanarObject:
    """A plain grey sheet over the board's face from (x0, y0) to (x1, y1), 1 mm above it."""
    tex = np.full((64, 64), 120, np.uint8)
    sx, sy = (x1_m - x0_m) / 64, (y1_m - y0_m) / 64
    A = np.array([[sx, 0.0, x0_m + 0.5 * sx], [0.0, sy, y0_m + 0.5 * sy], [0.0, 0.0, 1.0]])
    return PlanarObject(tex, A, Pose(Rotation.identity(), np.array([0.0, 0.0, 0.001])), "cover")


def _window(w_m: float, h_m: float) -> list[PlanarObject]:
    """Sheets over all of the board but the square of one marker (column 2, row 3)."""
    sq = SPEC.square_m
    x0, x1, y0, y1 = 2 * sq - 0.002, 3 * sq + 0.002, 3 * sq - 0.002, 4 * sq + 0.002
    return [cover(-0.05, x0, -0.05, h_m + 0.05), cover(x1, w_m + 0.05, -0.05, h_m + 0.05),
            cover(x0, x1, -0.05, y0), cover(x0, x1, y1, h_m + 0.05)]  # fmt: skip


def occluded_sequence(n: int, kind: str, seed: int = 0) -> tuple[list[np.ndarray], list[Pose]]:
    """``n`` renders of the 5x7 board and the true ``T_W_B`` of the vehicle (thesis mount)
    turning as it goes. ``half``: the board's left half covered, the vehicle 0.25 to 0.5 m up
    drifting across the covered edge; ``one marker``: all of it covered but one marker, the
    vehicle circling over it 0.3 to 0.9 m up."""
    w_m, h_m = SPEC.squares_x * SPEC.square_m, SPEC.squares_y * SPEC.square_m
    board = board_object(CharucoTarget(SPEC).board, (w_m, h_m), Pose.identity(), px_per_m=2000)
    sheets = [cover(-0.05, 0.5 * w_m, -0.05, h_m + 0.05)] if kind == "half" else _window(w_m, h_m)
    scene = SyntheticCamera(thesis_camera(), [board, *sheets],
                            RenderSettings(noise_sigma=2.0, seed=seed))  # fmt: skip
    rng = np.random.default_rng(seed)
    images, truth = [], []
    for k in range(n):
        a = 2 * np.pi * k / max(n - 1, 1)
        if kind == "half":
            p = np.array([w_m * (0.55 + 0.3 * np.sin(3 * a)), h_m * (0.5 + 0.4 * np.sin(a)),
                          0.25 + 0.25 * (0.5 - 0.5 * np.cos(2 * a))])  # fmt: skip
        else:
            sq = SPEC.square_m
            p = np.array([2.5 * sq + 0.08 * np.sin(3 * a), 3.5 * sq + 0.08 * np.cos(2 * a),
                          0.3 + 0.6 * (0.5 - 0.5 * np.cos(2 * a))])  # fmt: skip
        R = Rotation.from_euler("ZYX", [0.6 * np.sin(a), 0.12 * np.sin(5 * a), 0.12 * np.cos(4 * a)])  # fmt: skip
        T_W_B = Pose(R, p + rng.normal(0, 0.0005, 3))
        truth.append(T_W_B)
        images.append(scene.render(T_W_B @ thesis_mount()))
    return images, truth


def _steps(run: Path) -> tuple[float, float, np.ndarray, np.ndarray]:
    rows = list(csv.DictReader((run / "poses.csv").open()))
    f = np.array([int(r["frame"]) for r in rows])
    p = np.array([[float(r[k]) for k in ("x_m", "y_m", "z_m")] for r in rows]).reshape(-1, 3)
    ok = np.isfinite(p[:, 0])
    both = ok[1:] & ok[:-1] & (np.diff(f) == 1)
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)[both]
    rms = float(np.sqrt(np.mean(step**2))) if len(step) else float("nan")
    return rms, float(step.max()) if len(step) else float("nan"), f, p


def measure(
    cfg: MarkersConfig, source: str, out: Path, truth: list[Pose] | None
) -> dict[str, float]:
    stats = run_markers(cfg, source, out)
    step_rms, step_max, f, p = _steps(stats.run_dir)
    row = {"jitter_rms_mm": stats.jitter_rms_mm, "jitter_median_mm": stats.jitter_median_mm,
           "fraction_with_pose": stats.fraction_with_pose, "step_rms_mm": 1e3 * step_rms,
           "step_max_m": step_max, "frames": stats.frames}  # fmt: skip
    if truth is not None:
        ok = np.isfinite(p[:, 0])
        err = np.linalg.norm(
            p[ok] - np.array([truth[i].p_A_B for i in f[ok]]).reshape(-1, 3), axis=1
        )
        row["error_rms_mm"] = 1e3 * float(np.sqrt(np.mean(err**2))) if len(err) else float("nan")
        row["error_max_m"] = float(err.max()) if len(err) else float("nan")
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description="the ChArUco marker fallback's jitter")
    parser.add_argument("--frames", type=int, default=400)
    parser.add_argument("--video-frames", type=int, default=1086)
    parser.add_argument(
        "--out", type=Path, default=Path("benchmarks/results/markers_fallback.json")
    )
    args = parser.parse_args()
    results: dict[str, dict[str, dict[str, float]]] = {}
    with tempfile.TemporaryDirectory() as tmp_:
        tmp = Path(tmp_)
        cal = tmp / "cal.yml"
        write_camera_yaml(cal, thesis_camera())
        synth = MarkersConfig(target="charuco", dictionary="DICT_6X6_250", camera_file=str(cal),
                              video=False, fps=40.0,
                              charuco={"squares_x": 5, "squares_y": 7, "square_m": 0.0475, "marker_m": 0.0285})  # fmt: skip
        sources = []
        for kind, name in (
            ("half", "rendered 5x7, half covered"),
            ("one", "rendered 5x7, 1 marker"),
        ):
            images, truth = occluded_sequence(args.frames, kind)
            (tmp / kind).mkdir()
            for k, im in enumerate(images):
                cv2.imwrite(str(tmp / kind / f"{k:05d}.png"), im)
            sources.append((name, synth, str(tmp / kind), truth))
        if args.video_frames > 0 and (DATA / "board12_17.mp4").exists():
            thesis = MarkersConfig(target="charuco", dictionary=2, camera_file=str(DATA / "cal.yml"),
                                   video=False, max_frames=args.video_frames)  # fmt: skip
            sources.append(("board12_17.mp4", thesis, str(DATA / "board12_17.mp4"), None))
        for name, cfg, source, tr in sources:
            results[name] = {}
            for label, fallback in (("fallback", True), ("no fallback", False)):
                c = cfg.model_copy(update={"charuco": cfg.charuco.model_copy(update={"marker_fallback": fallback})})  # fmt: skip
                results[name][label] = measure(c, source, tmp / f"{name}-{label}", tr)
    print(f"{'source':26s} {'':12s} {'jitter rms/med mm':>18s} {'with pose':>10s} "
          f"{'step rms mm':>12s} {'step max m':>11s} {'err rms mm':>11s} {'err max m':>10s}")  # fmt: skip
    for name, by in results.items():
        for label, r in by.items():
            print(f"{name:26s} {label:12s} {r['jitter_rms_mm']:8.2f} / {r['jitter_median_mm']:6.2f}"
                  f" {r['fraction_with_pose']:10.1%} {r['step_rms_mm']:12.1f} {r['step_max_m']:11.3f}"
                  f" {r.get('error_rms_mm', float('nan')):11.1f} {r.get('error_max_m', float('nan')):10.3f}")  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
