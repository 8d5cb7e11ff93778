"""Speed of the stereo SLAM (``quadnav.slam.SlamOdometry``, issue 24) on one core, per stage:
rectification, ORB on the left and on the right image, stereo matching, the search by
projection, the pose-only optimisation and local mapping (its bundle adjustment), in ms a
frame; the tracking rate (frames over the time of everything but local mapping, which ORB-SLAM2
runs in its own thread) and the whole rate (local mapping inline, as quadnav runs it); and the
whole process of ``quadnav slam DATASET`` (interpreter start, imports, reading the images,
metrics, plots and report included). At 672x376 (the ``zed`` rig) and 752x480 (``euroc``).

One core: the process pins itself to ``--core`` before anything is imported, and its children
(the runs, the whole process, ORB-SLAM3) inherit the mask; ``OMP_NUM_THREADS`` and the like are
1 and ``cv2.setNumThreads(1)``. Each figure is the best and the median of ``--repeats`` runs
over the same frames. ``--before SRC`` (a ``src/`` folder of another quadnav, e.g.
``git archive fc857bd src | tar -x -C /tmp/before``) measures that code too, in the same run,
a repeat of each in turn, so that both see the same machine. With ``--orb-venv`` (set up as
``../shared/peers/orbslam3/README.md`` says), ORB-SLAM3 stereo runs on the same dataset, unpaced,
``--repeats`` times on the same core: its mean tracking time a frame (``stats.json``, its local
mapping thread beside it on that core) and our tracking time over it.

    python benchmarks/slam.py [--zed DATASET] [--euroc DATASET] [--frames 0] [--repeats 3]
        [--process-repeats N] [--core 0] [--before SRC] [--orb-venv ../orb-venv]
        [--orb-dir ../shared/peers/orbslam3] [--out benchmarks/results/slam.json]

``--frames N``: the first N pairs only (the whole process too, through ``--duration``; ORB-SLAM3
reads the whole dataset); ``--process-repeats``: runs of the whole process (default
``--repeats``, 0: none).

Without a dataset: ``room_easy`` made once under ``benchmarks/results/datasets``, 4 s with the
``zed`` rig (60 Hz: 240 pairs) and 10 s with ``euroc`` (20 Hz: 200 pairs).
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
import functools  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections import Counter, defaultdict  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

#: the stages, in the order a frame meets them
STAGES = ("rectification", "ORB left", "ORB right", "stereo matching", "search by projection",
          "pose optimisation", "local mapping (BA)", "other")  # fmt: skip
DEFAULTS = {"zed": 4.0, "euroc": 10.0}  # room_easy's seconds per rig (about 200 pairs each)


def _timed(fn: Callable[..., Any], seconds: dict[str, float], name: Callable[[], str]) -> Any:
    """``fn`` adding its wall time to ``seconds[name()]`` and its CPU time to
    ``seconds["cpu " + name()]``."""

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            k = name()
            seconds[k] += time.perf_counter() - t0
            seconds["cpu " + k] += time.process_time() - c0

    return wrapper


def _same(image: Any) -> Any:
    return image


def measure_once(dataset: Path, frames: int = 0) -> dict[str, object]:
    """One run of the SLAM over ``dataset``'s first ``frames`` stereo pairs (0: all; the images
    read beforehand), each stage timed by wrapping the function the SLAM calls for it."""
    import cv2

    import quadnav.slam.frame as frame_mod
    import quadnav.slam.tracking as tracking_mod
    from quadnav.io.datasets import open_dataset
    from quadnav.messages import ImageFrame
    from quadnav.slam import SlamOdometry

    cv2.setNumThreads(1)
    ds = open_dataset(dataset)
    names = {c.name for c in ds.rig.cameras[:2]}
    images = [(s.t_ns, s.camera, s.image()) for s in ds.stream()
              if isinstance(s, ImageFrame) and s.camera in names]  # fmt: skip
    if frames > 0:
        images = images[: 2 * frames]
    stamps = sorted({t for t, _, _ in images})
    period_s = float(np.median(np.diff(stamps))) * 1e-9 if len(stamps) > 1 else 0.0
    odo = SlamOdometry(ds.rig)
    sec: dict[str, float] = defaultdict(float)
    calls: Counter[str] = Counter()  # (stereo_frame extracts the left image, then the right)

    def orb_side() -> str:
        calls["extract"] += 1
        return "ORB left" if calls["extract"] % 2 else "ORB right"

    assert odo.rectifier is not None  # (a stereo rig)
    odo.rectifier.rectify = _timed(odo.rectifier.rectify, sec, lambda: "rectification")  # type: ignore[method-assign]
    odo.extractor.extract = _timed(odo.extractor.extract, sec, orb_side)  # type: ignore[method-assign]
    saved = {m: {k: getattr(m, k) for k in ks} for m, ks in (
        (frame_mod, ("stereo_keypoints",)),
        (tracking_mod, ("search_by_projection", "optimize_pose", "local_mapping")))}  # fmt: skip
    labels: dict[str, str] = {"stereo_keypoints": "stereo matching", "search_by_projection": "search by projection",
              "optimize_pose": "pose optimisation", "local_mapping": "local mapping (BA)"}  # fmt: skip
    for m, funcs in saved.items():
        for k, f in funcs.items():
            setattr(m, k, _timed(f, sec, functools.partial(labels.__getitem__, k)))
    total, cpu, pairs, tracked = 0.0, 0.0, 0, 0
    try:
        for t_ns, cam, img in images:
            t0, c0 = time.perf_counter(), time.process_time()
            state = odo.push(ImageFrame(t_ns=t_ns, camera=cam, load=functools.partial(_same, img)))
            total += time.perf_counter() - t0
            cpu += time.process_time() - c0
            pairs += cam == ds.rig.cameras[1].name
            tracked += state is not None
    finally:
        for m, funcs in saved.items():
            for k, f in funcs.items():
                setattr(m, k, f)
    sec["other"] = total - sum(v for k, v in sec.items() if not k.startswith("cpu "))
    sec["cpu other"] = cpu - sum(v for k, v in sec.items() if k.startswith("cpu "))
    w, h = ds.rig.cameras[0].camera.width, ds.rig.cameras[0].camera.height
    return {"total_s": total, "cpu_s": cpu, "pairs": pairs, "period_s": period_s,
            "span_s": (stamps[-1] - stamps[0]) * 1e-9 if stamps else 0.0, "tracked": tracked, "stages_s": dict(sec),
            "resolution": [w, h], "keyframes": len(odo.tracker.map.keyframes)}  # fmt: skip


def _child(dataset: Path, src: Path | None, frames: int) -> dict[str, object]:
    """``measure_once`` in a fresh process (of ``src``'s quadnav when given)."""
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = str(src)
    cmd = [sys.executable, str(Path(__file__).resolve()), "--measure", str(dataset), str(frames)]
    cmd += ["--core", str(_CORE)]  # (the child pins itself too: to this core)
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    if done.returncode != 0:
        _fail(f"the measuring run on {dataset} failed: {done.stderr.strip()[-300:]}")
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


def _whole_process(dataset: Path, src: Path | None, span: list[str]) -> float:
    env = dict(os.environ, MPLBACKEND="Agg")
    if src is not None:
        env["PYTHONPATH"] = str(src)
    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "quadnav", "slam", str(dataset), *span, "--out", out],
                       check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)  # fmt: skip
        return time.perf_counter() - t0


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Best and median over repeats: ms a frame per stage, tracking and whole rates."""
    pairs = int(runs[0]["pairs"])

    def ms(x: float) -> float:
        return 1e3 * x / pairs

    per = {s: [ms(float(r["stages_s"].get(s, 0.0))) for r in runs] for s in STAGES}
    per_cpu = {s: [ms(float(r["stages_s"].get("cpu " + s, 0.0))) for r in runs] for s in STAGES}
    total = [ms(float(r["total_s"])) for r in runs]
    track = [t - lm for t, lm in zip(total, per["local mapping (BA)"], strict=True)]
    cpu = [ms(float(r["cpu_s"])) for r in runs]
    track_cpu = [t - lm for t, lm in zip(cpu, per_cpu["local mapping (BA)"], strict=True)]
    return {
        "pairs": pairs, "tracked": runs[0]["tracked"], "keyframes": runs[0]["keyframes"],
        "stage_ms_best": {s: min(v) for s, v in per.items()},
        "stage_ms_median": {s: float(np.median(v)) for s, v in per.items()},
        "tracking_ms_best": min(track), "tracking_ms_median": float(np.median(track)),
        "tracking_hz_best": 1e3 / min(track), "tracking_hz_median": 1e3 / float(np.median(track)),
        "total_ms_best": min(total), "total_ms_median": float(np.median(total)),
        "whole_hz_best": 1e3 / min(total), "all_total_ms": total,
        "stage_cpu_ms_best": {s: min(v) for s, v in per_cpu.items()},
        "tracking_cpu_ms_best": min(track_cpu), "tracking_cpu_hz_best": 1e3 / min(track_cpu),
        "total_cpu_ms_best": min(cpu),
    }  # fmt: skip


def _orb(dataset: Path, args: argparse.Namespace) -> dict[str, Any] | str:
    """ORB-SLAM3 stereo, unpaced, ``--repeats`` times: its tracking ms a frame (mean of each
    run's ``stats.json``), best and median; or why it did not run."""
    sys.path.insert(0, str(HERE))
    from orb_peer import OrbPeer, run_process

    peer = OrbPeer(args.orb_venv, args.orb_dir)
    if peer.missing():
        return f"ORB-SLAM3 not run: missing {peer.missing()}"
    with tempfile.TemporaryDirectory() as tmp:
        settings = Path(tmp) / "settings"
        peer.make_settings(dataset, settings)
        means = []
        for k in range(args.repeats):
            work = Path(tmp) / f"run{k}"
            work.mkdir()
            cmd = peer.command(dataset, "stereo", settings, work / "out", paced=False)
            run_process(cmd, work / "log.txt", 900.0)
            stats = work / "out" / "stats.json"
            if stats.is_file():
                means.append(float(json.loads(stats.read_text())["track_ms_mean"]))
    if not means:
        return "ORB-SLAM3 stereo left no stats.json"
    return {"track_ms_mean_best": min(means), "track_ms_mean_median": float(np.median(means)),
            "all_track_ms_mean": means, "version": peer.version()}  # fmt: skip


def _row(label: str, cells: list[tuple[float, float, float]], fmt: str = ".2f") -> str:
    text = "".join(f"{a:>10{fmt}} {b:>8{fmt}} {c:>8{fmt}}" for a, b, c in cells)
    return f"  {label:<22}{text}"


def _print(name: str, res: dict[str, Any]) -> None:
    """The table: per variant, wall ms a frame best and median of the repeats, and CPU ms best
    (the process's own time: less sensitive to other processes on the machine)."""
    vs = [res["variants"][v] for v in res["variants"]]
    w, h = res["resolution"]
    print(f"\n{name} ({w}x{h}, {vs[0]['pairs']} pairs), ms a frame")
    print(f"  {'':<22}" + "".join(f"{v:>28}" for v in res["variants"]))
    print(f"  {'stage':<22}" + f"{'wall best':>10} {'median':>8} {'CPU best':>8}" * len(vs))
    for s in STAGES:
        print(_row(s, [(v["stage_ms_best"][s], v["stage_ms_median"][s], v["stage_cpu_ms_best"][s])
                       for v in vs]))  # fmt: skip
    print(_row("tracking (no LM)", [(v["tracking_ms_best"], v["tracking_ms_median"],
                                     v["tracking_cpu_ms_best"]) for v in vs]))  # fmt: skip
    print(_row("whole frame", [(v["total_ms_best"], v["total_ms_median"], v["total_cpu_ms_best"])
                               for v in vs]))  # fmt: skip
    print(_row("tracking Hz", [(v["tracking_hz_best"], v["tracking_hz_median"],
                                v["tracking_cpu_hz_best"]) for v in vs], ".1f"))  # fmt: skip
    if all(res["process_s"].values()):
        print(_row("whole process (s)", [(min(t), float(np.median(t)), float("nan"))
                                         for t in res["process_s"].values()]))  # fmt: skip
    orb = res.get("orb")
    if isinstance(orb, dict):
        ours = vs[0]["tracking_ms_median"]
        print(f"  ORB-SLAM3 stereo: tracking {orb['track_ms_mean_best']:.1f} ms a frame best, "
              f"{orb['track_ms_mean_median']:.1f} median (unpaced, same core); ours / ORB-SLAM3 "
              f"(wall medians): {ours / orb['track_ms_mean_median']:.2f}")  # fmt: skip
    elif orb:
        print(f"  {orb}")


def _measure(name: str, dataset: Path, args: argparse.Namespace) -> dict[str, Any]:
    srcs: dict[str, Path | None] = {"now": None}
    if args.before is not None:
        srcs["before"] = args.before
    runs: dict[str, list[dict[str, Any]]] = {v: [] for v in srcs}
    process: dict[str, list[float]] = {v: [] for v in srcs}
    for _ in range(args.repeats):
        for v, src in srcs.items():  # (in turn: both see the same machine)
            runs[v].append(_child(dataset, src, args.frames))
    first = runs["now"][0]  # (the whole process over the same pairs)
    span = (
        [] if args.frames <= 0 else ["--duration", f"{first['span_s'] + first['period_s'] / 2:.4f}"]
    )
    for _ in range(args.process_repeats):
        for v, src in srcs.items():
            process[v].append(_whole_process(dataset, src, span))
    res: dict[str, Any] = {
        "dataset": str(dataset), "resolution": runs["now"][0]["resolution"],
        "variants": {v: summarise(r) for v, r in runs.items()}, "process_s": process,
        "load_average": os.getloadavg(),
    }  # fmt: skip
    if args.orb_venv is not None:
        res["orb"] = _orb(dataset, args)
    _print(name, res)
    return res


def _dataset(rig: str, given: Path | None) -> Path:
    if given is not None:
        if not (given / "mav0").is_dir():
            _fail(f"--{rig} {given}: not an EuRoC folder (no mav0/)")
        return given
    from quadnav.experiments.odometry_run import resolve_dataset

    ds = resolve_dataset("room_easy", rig=rig, duration_s=DEFAULTS[rig],
                         cache_root=ROOT / "benchmarks" / "results")  # fmt: skip
    return Path(ds.root)


def main() -> None:
    if "--measure" in _ARGS:  # (a child: one run, JSON on the last line)
        at = _ARGS.index("--measure")
        print(json.dumps(measure_once(Path(_ARGS[at + 1]), int(_ARGS[at + 2]))))
        return
    parser = argparse.ArgumentParser(description="stereo SLAM speed on one core, per stage")
    parser.add_argument("--zed", type=Path, default=None, help="a 672x376 stereo EuRoC folder")
    parser.add_argument("--euroc", type=Path, default=None, help="a 752x480 stereo EuRoC folder")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--frames", type=int, default=0, help="the first N pairs (0: all)")
    parser.add_argument("--process-repeats", type=int, default=None, help="[default: --repeats]")
    parser.add_argument("--core", type=int, default=0)
    parser.add_argument("--before", type=Path, default=None, help="another quadnav's src/")
    parser.add_argument("--orb-venv", type=Path, default=None)
    parser.add_argument(
        "--orb-dir", type=Path, default=ROOT.parent / "shared" / "peers" / "orbslam3"
    )
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/slam.json"))
    args = parser.parse_args()
    args.process_repeats = args.repeats if args.process_repeats is None else args.process_repeats
    for option, value, low in (("--repeats", args.repeats, 1), ("--frames", args.frames, 0),
                               ("--process-repeats", args.process_repeats, 0)):  # fmt: skip
        if value < low:
            _fail(f"{option} must be at least {low}, got {value}")
    if args.before is not None and not (args.before / "quadnav" / "slam").is_dir():
        _fail(f"--before {args.before}: not a quadnav src/ folder with quadnav/slam/")
    import cv2
    import gtsam

    from quadnav.io.run_folder import write_text

    print(f"stereo SLAM speed, one core (affinity {sorted(os.sched_getaffinity(0))}), "
          f"{args.repeats} repeats, load average {os.getloadavg()[0]:.2f}")  # fmt: skip
    results = {
        rig: _measure(rig, _dataset(rig, getattr(args, rig)), args) for rig in ("zed", "euroc")
    }
    write_text(args.out, json.dumps({
        "benchmark": "slam", "python": platform.python_version(), "opencv": cv2.__version__,
        "gtsam": getattr(gtsam, "__version__", "?"), "core": args.core, "repeats": args.repeats,
        "before": str(args.before) if args.before else None, "stages": STAGES, "results": results,
    }, indent=2) + "\n")  # fmt: skip
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
