"""Frames per second of the feature tracker (``FeatureTracker.track``) on one core, per stage:
prepare (checks, optional CLAHE), KLT (forward), FB check (KLT back), RANSAC (fundamental
matrix on undistorted pixels), detect (spacing, mask, Shi-Tomasi top-up).

Frames: euroc_micro's real cam0 images (752x480, vehicle at rest: KLT converges at once, few new
corners), the same at a 640x480 centre crop, and a moving sequence at both sizes: the first real
frame seen through a homography that pans 3 px and turns 0.3 degrees a frame (VINS' 150
features, a real image's texture, features leaving and entering). Each set is tracked
``--repeats`` times; a frame's time in a stage is its least over the repeats (the least
disturbed), summed over the frames.
Also prints the track statistics of euroc_micro's cam0 and cam1 (median track length, fraction
tracked frame to frame...) and its cam0 -> cam1 stereo matches. Prints tables and writes ``benchmarks/results/tracking.json``.

    python benchmarks/tracking.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from dataclasses import fields
from pathlib import Path

import cv2
import numpy as np

from quadnav.geometry.camera import PinholeCamera
from quadnav.rig import euroc
from quadnav.vision.tracking import (
    FeatureTracker,
    StageTimes,
    StereoGeometry,
    TrackerConfig,
    track_sequence,
    track_stereo,
)

CAM0 = (
    Path(__file__).resolve().parents[1].parent / "shared" / "data" / "euroc_micro" / "mav0" / "cam0"
)
STAGES = [f.name for f in fields(StageTimes)]


def moving(first: np.ndarray, n: int) -> list[np.ndarray]:
    """The image panned 3 px right and 1.5 px down and turned 0.3 degrees about its centre a
    frame, from a 1.3x zoom so that no border comes in."""
    h, w = first.shape
    out = []
    for k in range(n):
        M = cv2.getRotationMatrix2D((w / 2, h / 2), 0.3 * k, 1.3)
        M[:, 2] += (3.0 * k - 1.5 * n, 1.5 * k - 0.75 * n)
        out.append(cv2.warpAffine(first, M, (w, h), flags=cv2.INTER_LINEAR))
    return out


def best_stage_s(
    frames: list[np.ndarray],
    cam: PinholeCamera | None,
    repeats: int,
    config: TrackerConfig | None = None,
) -> dict[str, float]:
    """Per stage, the sum over the frames of each frame's least time among ``repeats`` runs
    (a run tracks the same frames the same way, so the least is the least disturbed), with
    ``config`` (default: ``TrackerConfig()``)."""
    t = np.full((repeats, len(frames), len(STAGES) + 1), np.inf)
    for r in range(repeats):
        tr = FeatureTracker(config or TrackerConfig(), cam)
        for k, img in enumerate(frames):
            t0 = time.perf_counter()
            tr.track(k * 50_000_000, img)
            t[r, k, -1] = time.perf_counter() - t0
            t[r, k, :-1] = [getattr(tr.last_times, s) for s in STAGES]
    best = t.min(axis=0).sum(axis=0)
    return {**dict(zip(STAGES, best[:-1].tolist(), strict=True)), "total_s": float(best[-1])}


def euroc_track_stats() -> dict[str, dict[str, float]]:
    """Track statistics of euroc_micro's cam0 and cam1 (rig calibration), plain and with CLAHE:
    the tracker's quality on real frames, printed with its speed."""
    out = {}
    for spec in euroc().cameras:
        for eq in (False, True):
            files = sorted((CAM0.parent / spec.name / "data").glob("*.png"))
            imgs = ((int(f.stem), cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)) for f in files)
            st = track_sequence(imgs, TrackerConfig(equalize=eq), spec.camera)
            out[spec.name + (" equalize" if eq else "")] = {
                "median_track_length": st.track_length.median, "mean_track_length": st.track_length.mean,
                "fraction_tracked_mean": st.fraction_tracked.mean, "fraction_tracked_min": st.fraction_tracked.min,
                "features_per_frame": st.features_per_frame.mean, "new_per_frame": st.new_per_frame.mean,
            }  # fmt: skip
    print(f"{'euroc_micro':<16}" + "".join(f" {k:>22}" for k in next(iter(out.values()))))
    for name, r in out.items():
        print(f"{name:<16}" + "".join(f" {v:>22.4g}" for v in r.values()))
    return out


def euroc_stereo_stats() -> dict[str, float]:
    """cam0 -> cam1 matches of euroc_micro's 95 pairs with the rig's epipolar geometry (CLAHE)."""
    c0, c1 = euroc().cameras
    geo = StereoGeometry(left=c0.camera, right=c1.camera, T_L_R=c0.T_B_C.inverse() @ c1.T_B_C)
    n, err = [], []
    for f in sorted((CAM0 / "data").glob("*.png")):
        left = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(CAM0.parent / "cam1" / "data" / f.name), cv2.IMREAD_GRAYSCALE)
        m = track_stereo(left, right, config=TrackerConfig(equalize=True), geometry=geo)
        n.append(len(m))
        err.append(geo.epipolar_error_px(m.left_px, m.right_px))
    e = np.concatenate(err)
    out = {"matches_per_pair": float(np.mean(n)), "epipolar_error_median_px": float(np.median(e)),
           "epipolar_error_p95_px": float(np.percentile(e, 95))}  # fmt: skip
    print(
        "euroc_micro stereo (cam0 -> cam1, equalize): "
        + ", ".join(f"{k} {v:.3g}" for k, v in out.items())
    )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description="feature tracker speed")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/tracking.json"))
    args = parser.parse_args()
    cv2.setNumThreads(1)  # one core, as the issue asks
    real = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((CAM0 / "data").glob("*.png"))]
    if not real:
        raise SystemExit(f"euroc_micro not found at {CAM0}")
    cam = euroc().cameras[0].camera
    crop = [im[:, 56:696].copy() for im in real]  # 640x480 of the centre
    sets = {
        "euroc cam0 752x480 (at rest)": (real, cam),
        "euroc cam0 640x480 crop (at rest)": (crop, None),
        "moving 752x480 (real texture)": (moving(real[0], len(real)), None),
        "moving 640x480 (real texture)": (moving(crop[0], len(crop)), None),
    }
    results = {}
    for name, (frames, c) in sets.items():
        best = best_stage_s(frames, c, args.repeats)
        n = len(frames)
        results[name] = {"frames": n, "fps": n / best["total_s"], **{f"{s[:-2]}_ms": best[s] / n * 1e3 for s in STAGES}}  # fmt: skip
    stats = euroc_track_stats()
    stereo = euroc_stereo_stats()
    head = f"{'frames':<36} {'n':>4} {'fps':>7}" + "".join(f" {s[:-2] + ' ms':>11}" for s in STAGES)
    print(head)
    for name, r in results.items():
        print(f"{name:<36} {r['frames']:>4} {r['fps']:>7.0f}" + "".join(f" {r[s[:-2] + '_ms']:>11.2f}" for s in STAGES))  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"benchmark": "tracking", "python": platform.python_version(), "opencv": cv2.__version__,
                                    "threads": 1, "repeats": args.repeats, "sets": results, "euroc_track_stats": stats, "euroc_stereo": stereo}, indent=2) + "\n")  # fmt: skip
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
