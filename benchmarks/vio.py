"""Speed of the VIO (``quadnav.vio.VioEstimator``) on one core: camera frames per second at the
dataset's resolution (752x480 for EuRoC's cam0 and the ``euroc_mono`` rig), per stage (the
estimator's own ``timing()``), beside the feature tracker alone on the same frames with the
VIO's tracker settings (``benchmarks/tracking.py``'s measurement, same run); and the whole process of
``quadnav vio DATASET --no-video`` on those frames (interpreter start, imports, reading the
images, metrics, plots and report included).

One core: the process pins itself to ``--core`` with ``sched_setaffinity`` before anything is
imported (GTSAM's TBB and OpenCV size their thread pools from the affinity mask they see, and a
child process inherits it), and sets ``OMP_NUM_THREADS``/``OPENBLAS_NUM_THREADS``/
``MKL_NUM_THREADS`` to 1 and ``cv2.setNumThreads(1)``. Each in-process figure is given as the
best and the median of ``--repeats`` runs over the same frames (other sessions share the
machine), per stage too; the whole process likewise.

The peer, VINS-Mono (C++/ROS), cannot be installed here: the tracker ratio is the comparison
this benchmark can make (VINS-Mono's own front end is the same GFTT + KLT).

    python benchmarks/vio.py [DATASET] [--frames 200] [--repeats 3] [--core 0]
        [--out benchmarks/results/vio.json]

Without DATASET: 10 s of ``room_easy`` with the ``euroc_mono`` rig, made once under
``benchmarks/results/datasets``.
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from one_core import fail as _fail
from one_core import pin_to_core

# Before numpy, OpenCV or GTSAM load: their thread pools see one core.
_ARGS = sys.argv[1:]
_CORE = pin_to_core(_ARGS)

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import gtsam  # noqa: E402
import numpy as np  # noqa: E402

from quadnav.errors import QuadnavError  # noqa: E402
from quadnav.experiments.vio_run import resolve_dataset  # noqa: E402
from quadnav.io.datasets import VisualInertialDataset, open_dataset  # noqa: E402
from quadnav.io.run_folder import write_text  # noqa: E402
from quadnav.messages import ImageFrame, ImuSample  # noqa: E402
from quadnav.vio import VioConfig, VioEstimator  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from tracking import best_stage_s  # noqa: E402

Item = tuple[int, str, ImuSample | np.ndarray]


#: The configurations compared in one run: the window as it was before issue 22's speed work
#: (batch Levenberg-Marquardt over the window at each keyframe, the extrinsic fixed), today's
#: window with the front end's setting as it was before (VINS-Mono's: corners detected whenever
#: one is missing), and today's defaults (iSAM2, the extrinsic refined online, corners detected
#: once 20 are missing), and today's defaults with KLT started from the gyro's prediction
#: (``predict_flow``). All match a stereo frame's corners in the right image at
#: keyframes only (before, every frame was matched: about 25 ms a frame more). The vectorised
#: spacing check and landmark admission give the same results and are in all three.
def _before() -> VioConfig:
    return VioConfig(smoother="batch", estimate_extrinsic=False)


def _front_end_before() -> VioConfig:
    cfg = VioConfig()
    vins = cfg.tracker.model_copy(update={"detect_min_new": 1})
    return cfg.model_copy(update={"tracker": vins})


def _predicted_flow() -> VioConfig:
    """KLT started from the gyro's rotation of each feature (VINS-Fusion's, OpenVINS')."""
    return VioConfig(predict_flow=True)


CONFIGS = {
    "before (batch smoother, fixed extrinsic)": _before,
    "front end before (VINS' settings)": _front_end_before,
    "default": VioConfig,
    "gyro-predicted flow": _predicted_flow,
}


def _items(
    ds: VisualInertialDataset, cameras: tuple[str, ...], n_frames: int
) -> tuple[list[Item], float]:
    """The first ``n_frames`` images of the first of ``cameras`` (and the others' images up to
    then, loaded) and the IMU samples up to the last, in time order; and the span in seconds."""
    items: list[Item] = []
    frames = 0
    t0 = None
    for s in ds.stream():
        t0 = s.t_ns if t0 is None else t0
        if isinstance(s, ImuSample):
            items.append((s.t_ns, "", s))
        elif s.camera in cameras:
            if frames == n_frames:
                break
            items.append((s.t_ns, s.camera, s.image()))
            frames += s.camera == cameras[0]
    return items, (items[-1][0] - (t0 or 0)) * 1e-9


def _one_run(
    ds: VisualInertialDataset, items: list[Item], camera: str, config: VioConfig
) -> dict[str, object]:
    vio = VioEstimator(ds.rig, config, camera=camera)
    total = 0.0
    frames = 0
    estimates = 0
    for t_ns, cam, x in items:
        t = time.perf_counter()
        if isinstance(x, ImuSample):
            vio.push(x)
        else:
            frame = ImageFrame(t_ns=t_ns, camera=cam, load=lambda x=x: x)
            estimates += vio.push(frame) is not None
            vio.keyframes()
            frames += cam == camera
        total += time.perf_counter() - t
    stages = {name: (s, n) for name, s, n in vio.timing().stages}
    return {"total_s": total, "frames": frames, "estimates": estimates, "stages": stages}


def _best_in_process(
    ds: VisualInertialDataset, items: list[Item], camera: str, repeats: int, config: VioConfig
) -> dict[str, object]:
    runs = [_one_run(ds, items, camera, config) for _ in range(repeats)]
    best = min(runs, key=lambda r: float(r["total_s"]))  # type: ignore[arg-type]
    frames = int(best["frames"])  # type: ignore[call-overload]
    names = list(best["stages"])  # type: ignore[call-overload]
    per_frame = {
        n: 1e3 * min(r["stages"][n][0] for r in runs if n in r["stages"]) / frames
        for n in names  # type: ignore[index,operator]
    }
    median = {
        n: 1e3 * float(np.median([r["stages"][n][0] for r in runs if n in r["stages"]])) / frames
        for n in names  # type: ignore[index,operator]
    }
    fps = [int(r["frames"]) / float(r["total_s"]) for r in runs]  # type: ignore[call-overload,arg-type]
    return {
        "frames": frames, "estimates": best["estimates"],
        "frames_per_s": frames / float(best["total_s"]),  # type: ignore[arg-type]
        "median_frames_per_s": float(np.median(fps)), "all_frames_per_s": fps,
        "stage_ms_per_frame": per_frame, "stage_ms_per_frame_median": median,
        "stage_calls": {n: best["stages"][n][1] for n in names},  # type: ignore[index]
    }  # fmt: skip


def _whole_process(source: Path, span_s: float, repeats: int, stereo: bool) -> list[float]:
    """The wall time (s) of each of ``repeats`` runs of ``quadnav vio --no-video``."""
    times = []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as out:
            t0 = time.perf_counter()
            subprocess.run(
                [sys.executable, "-m", "quadnav", "vio", str(source), "--no-video",
                 "--duration", f"{span_s:.3f}", "--out", out] + (["--stereo"] if stereo else []),
                check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            )  # fmt: skip
            times.append(time.perf_counter() - t0)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description="VIO speed on one core")
    parser.add_argument("dataset", nargs="?", type=Path, default=None)
    parser.add_argument("--camera", default="cam0")
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--core", type=int, default=0)
    parser.add_argument("--stereo", action="store_true", help="stereo-inertial runs too")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/vio.json"))
    args = parser.parse_args()
    if args.dataset is not None and not args.dataset.exists():
        _fail(f"DATASET {args.dataset}: no such file or folder")
    for option, value in (("--frames", args.frames), ("--repeats", args.repeats)):
        if value < 1:
            _fail(f"{option} must be at least 1, got {value}")
    cv2.setNumThreads(1)
    try:
        _measure(args)
    except QuadnavError as exc:
        _fail(str(exc))


def _configs(stereo: bool) -> dict[str, VioConfig]:
    out = {}
    for name, make in CONFIGS.items():
        cfg = make()
        out[name] = cfg
        if stereo:
            out[f"{name}, stereo"] = cfg.model_copy(update={"stereo": True})
    return out


def _print_table(name: str, vio: dict[str, object]) -> None:
    print(f"{name}: {vio['frames_per_s']:.1f} frames/s best, {vio['median_frames_per_s']:.1f} "
          "median (all repeats: "
          + ", ".join(f"{x:.1f}" for x in vio["all_frames_per_s"]) + ")")  # type: ignore[attr-defined]  # fmt: skip
    print(f"  {'stage':<16}{'ms/frame best':>15}{'median':>10}{'calls':>8}")
    for n, ms in vio["stage_ms_per_frame"].items():  # type: ignore[attr-defined]
        med = vio["stage_ms_per_frame_median"][n]  # type: ignore[index]
        print(f"  {n:<16}{ms:>15.2f}{med:>10.2f}{vio['stage_calls'][n]:>8}")  # type: ignore[index]


def _measure(args: argparse.Namespace) -> None:
    if args.dataset is None:
        ds = resolve_dataset("room_easy", duration_s=10.0, cache_root=Path("benchmarks/results"))
    else:
        ds = open_dataset(args.dataset)
    cam = ds.rig.camera(args.camera)
    cameras: tuple[str, ...] = (args.camera,)
    if args.stereo:
        others = [c.name for c in ds.rig.cameras if c.name != args.camera]
        if not others:
            _fail(f"--stereo: the dataset's rig {ds.rig.name!r} has one camera")
        cameras = (args.camera, others[0])
    items, span_s = _items(ds, cameras, args.frames)
    images = [x for _, c, x in items if c == args.camera and isinstance(x, np.ndarray)]
    w, h = cam.camera.width, cam.camera.height
    print(f"VIO on {ds.name} ({w}x{h}), {len(images)} frames over {span_s:.1f} s, one core "
          f"(affinity {sorted(os.sched_getaffinity(0))}), best of {args.repeats}")  # fmt: skip
    runs = {}
    for name, cfg in _configs(args.stereo).items():
        runs[name] = _best_in_process(ds, items, args.camera, args.repeats, cfg)
        _print_table(name, runs[name])
    tracker = best_stage_s(images, cam.camera, args.repeats, VioConfig().tracker)
    tracker_fps = len(images) / tracker["total_s"]
    process = {"mono": _whole_process(ds.root, span_s, args.repeats, False)}
    if args.stereo:
        process["stereo"] = _whole_process(ds.root, span_s, args.repeats, True)
    base = float(runs["default"]["frames_per_s"])  # type: ignore[arg-type]
    print(f"{'tracker alone frames/s':<28}{tracker_fps:>10.1f}")
    print(f"{'VIO / tracker':<28}{base / tracker_fps:>10.2f}")
    for mode, secs in process.items():
        print(f"{'whole process ' + mode + ' (s)':<28}{min(secs):>10.2f} best "
              f"{float(np.median(secs)):.2f} median   quadnav vio --no-video")  # fmt: skip
    write_text(args.out, json.dumps({
        "benchmark": "vio", "python": platform.python_version(), "opencv": cv2.__version__,
        "gtsam": getattr(gtsam, "__version__", "?"), "core": args.core, "repeats": args.repeats,
        "dataset": str(ds.root), "resolution": [w, h], "span_s": span_s, "frames": len(images),
        "configs": {n: c.model_dump(mode="json") for n, c in _configs(args.stereo).items()},
        "vio": runs, "tracker_alone_frames_per_s": tracker_fps,
        "vio_over_tracker": base / tracker_fps,
        "whole_process_s": {m: min(t) for m, t in process.items()}, "whole_process_all_s": process,
        "peer": "ORB-SLAM3 on the same data: benchmarks/vio_peer.py",
    }, indent=2) + "\n")  # fmt: skip
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
