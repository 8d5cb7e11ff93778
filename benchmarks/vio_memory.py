"""Memory of a long VIO or SLAM run (issue 22, item 9: the peak RSS of a 30-minute sequence
within 1.2x of a 3-minute one's; issue 24: the SLAM's): ``quadnav.vio.VioEstimator`` (or,
``--odometry slam``, ``quadnav.slam.SlamOdometry`` on a stereo ``--rig`` such as ``euroc``, its
final adjustment included) through the one odometry runner
(``experiments/odometry_run.py`` ``run_odometry``, as ``quadnav vio`` runs it, no video) on a
built-in sequence's motion (its Lissajous flight loops its room for as long as it is asked),
for each ``--minutes``, each in its own process. The images are rendered when the runner reads
them (``experiments/datasets.py`` ``rendered_dataset``: the renderer of ``quadnav dataset
make``), none written or kept.

Each child reports its resident set (``/proc/self/status``): after imports, after building the
dataset (the input: the IMU table, the ground truth, one lazy frame per image and the motion),
the peak of that set-up, then every ``--every`` camera frames of the run (the growth curve), and
the run's own peak (the peak is reset after the set-up through ``/proc/self/clear_refs``);
the parent reads each child's peak after the reset (``ru_maxrss`` from ``wait4``): the
whole-process peak is the larger of that and the set-up's. Printed: the
table, the growth in kB per minute of run, and the ratios of the longest to the shortest run.
The runner keeps the trajectory it writes (one row a camera frame with an estimate): that is the
output's cost, given per frame, apart from the estimator's.

One core: the process pins itself to ``--core`` before numpy, OpenCV or GTSAM load (children
inherit the mask), as ``benchmarks/vio.py`` does; importing the script (its tests) pins nothing.

    python benchmarks/vio_memory.py [--minutes 3 30] [--odometry vio] [--sequence room_easy] [--rig euroc_mono]
        [--sensors ideal] [--seed 0] [--every 200] [--scale 1] [--core 0]
        [--out benchmarks/results/vio_memory.json]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

#: What a child prints before its JSON line, so that the parent finds it among other output.
RESULT_TAG = "vio_memory_result "
#: glibc's mmap threshold in the children, fixed (its default grows to 32 MB after a large
#: array is freed): the set-up's large temporary arrays (the 1 kHz motion a 30-minute sequence
#: is fitted from) go back to the system when freed instead of leaving holes in the heap that
#: the run's allocations then touch again, which would count the set-up's size as the run's.
MMAP_THRESHOLD = 128 * 1024
SEQUENCES = ("room_easy", "room_medium", "room_difficult", "hall_easy", "hall_difficult", "yard")


def _fail(message: str) -> None:
    """A bad input: one line naming the option, exit code 2 (as the CLI does)."""
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


# -- the resident set ---------------------------------------------------------------------------


def proc_status_kb(text: str) -> dict[str, int]:
    """``VmRSS``, ``VmHWM`` (peak) ... of a ``/proc/<pid>/status`` text, in kB."""
    out: dict[str, int] = {}
    for line in text.splitlines():
        key, _, rest = line.partition(":")
        parts = rest.split()
        if key.startswith("Vm") and len(parts) == 2 and parts[1] == "kB":
            out[key] = int(parts[0])
    return out


def _status() -> dict[str, int]:
    return proc_status_kb(Path("/proc/self/status").read_text())


def _rss_kb() -> int:
    """The resident set now (``/proc/self/statm``: cheaper than ``status``), in kB."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") // 1024


def _reset_peak() -> bool:
    """Return freed heap to the system and reset ``VmHWM`` to the resident set now (Linux 4.0+);
    False where the peak cannot be reset (the run's peak is then the whole process's)."""
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        return False
    return True


# -- one run (the child) ------------------------------------------------------------------------


def _child(args: argparse.Namespace) -> dict[str, object]:
    import gc

    import cv2

    from quadnav.experiments.datasets import rendered_dataset, sequence_spec
    from quadnav.experiments.odometry_run import OdometryRunOptions, run_odometry

    cv2.setNumThreads(1)
    rss: dict[str, object] = {"imports": _rss_kb()}
    tic = time.perf_counter()
    fields = {"rig": args.rig, "seed": args.seed, "sensors": args.sensors}
    spec = sequence_spec(args.sequence, {**fields, "duration_s": 60.0 * args.child})
    dataset = rendered_dataset(spec, name=args.sequence, scale=args.scale)
    gc.collect()
    setup = _status()
    rss["setup_peak"] = setup["VmHWM"]
    reset = _reset_peak()
    rss["dataset"] = _rss_kb()
    setup_s = time.perf_counter() - tic
    samples: list[tuple[int, float, int]] = []

    def progress(done: int, total: int, text: str) -> None:
        if done % args.every == 0 or done == total:
            samples.append((done, time.perf_counter() - tic - setup_s, _rss_kb()))

    made: list[Any] = []
    maker = _odometry(args.odometry)

    def make(rig: Any) -> Any:
        made.append(maker(rig))
        return made[-1]

    with tempfile.TemporaryDirectory() as out:
        run = run_odometry(
            dataset, dataset.rig, make,
            Path(out), options=OdometryRunOptions(video=False), name=args.sequence,
            progress=progress,
        )  # fmt: skip
    end = _status()
    rss["run_peak"] = end["VmHWM"] if reset else None
    rss["final"] = end["VmRSS"]
    m = run.metrics
    ape = m.ape_se3 if isinstance(m.ape_se3, str) else m.ape_se3.rmse_m
    return {
        "minutes": args.child, "frames": m.frames, "frames_with_estimate": m.frames_with_estimate,
        "failures": m.failures, "reinitializations": m.reinitializations, "ape_se3_m": ape,
        "setup_s": setup_s, "run_s": run.timing.wall_s, "frames_per_s": run.timing.frames_per_s,
        "rss_kb": rss, "peak_reset": reset, "samples": samples, "map": _map_size(made),
    }  # fmt: skip


def _map_size(made: Sequence[Any]) -> dict[str, int] | None:
    """The SLAM's map at the end: keyframes (all, and not culled), points, and the bytes of
    its arrays (``SlamMap.nbytes``); None for the VIO."""
    m = getattr(made[0], "slam_map", None) if made else None
    if m is None:
        return None
    good = sum(not kf.bad for kf in m.keyframes)
    return {"keyframes": len(m.keyframes), "good_keyframes": good, "points": len(m),
            "nbytes": m.nbytes()}  # fmt: skip


def _odometry(kind: str) -> Callable[[Any], Any]:
    """The estimator's maker for the runner."""
    if kind == "slam":
        from quadnav.slam.odometry import SlamOdometry

        return lambda rig: SlamOdometry(rig)
    from quadnav.vio import VioConfig, VioEstimator

    return lambda rig: VioEstimator(rig, VioConfig(), camera="cam0")


# -- the parent ---------------------------------------------------------------------------------


def parse_child_output(stdout: str) -> dict[str, object]:
    """The child's result: the JSON after :data:`RESULT_TAG` on its last such line."""
    lines = [ln for ln in stdout.splitlines() if ln.startswith(RESULT_TAG)]
    if not lines:
        raise ValueError("the child printed no result line")
    out = json.loads(lines[-1][len(RESULT_TAG) :])
    if not isinstance(out, dict):
        raise ValueError("the child's result is not a JSON object")
    return out


def _run_child(args: argparse.Namespace, minutes: float) -> dict[str, object]:
    cmd = [sys.executable, __file__, "--child", f"{minutes:g}", "--core", str(args.core)]
    cmd += ["--sequence", args.sequence, "--rig", args.rig, "--sensors", args.sensors]
    cmd += ["--odometry", args.odometry]
    cmd += ["--seed", str(args.seed), "--every", str(args.every), "--scale", f"{args.scale:g}"]
    env = {**os.environ, "MALLOC_MMAP_THRESHOLD_": str(MMAP_THRESHOLD)}
    with tempfile.TemporaryFile("w+") as stdout:
        proc = subprocess.Popen(cmd, stdout=stdout, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        stdout.seek(0)
        text = stdout.read()
    if proc.returncode != 0:
        return {"minutes": minutes, "error": f"n/a: the run failed (exit {proc.returncode})"}
    out = parse_child_output(text)
    out["whole_process_peak_kb"] = whole_process_peak_kb(out, usage.ru_maxrss)
    return out


def whole_process_peak_kb(child: Mapping[str, object], ru_maxrss_kb: int) -> int:
    """The child's peak over its life: ``ru_maxrss`` (kB on Linux) is the peak since the child
    reset it after its set-up, so the set-up's peak, which it reported, counts too."""
    rss = child["rss_kb"]
    assert isinstance(rss, Mapping)
    return max(int(ru_maxrss_kb), int(rss["setup_peak"]))


def growth_kb_per_min(samples: Sequence[Sequence[float]], skip_min: float = 1.0) -> float | None:
    """The slope (kB per minute of run time) of the resident set over the samples after the
    first ``skip_min`` minutes (the window fills, the caches warm); None with fewer than 3."""
    import numpy as np

    rows = [(float(t) / 60.0, float(kb)) for _, t, kb in samples if float(t) / 60.0 >= skip_min]
    if len(rows) < 3:
        return None
    t, kb = np.array(rows).T
    return float(np.polyfit(t, kb, 1)[0])


def ratios(short: Mapping[str, object], long: Mapping[str, object]) -> dict[str, float | str]:
    """Longest over shortest run: whole-process peak, the run's own peak, the input's size."""
    out: dict[str, float | str] = {}
    if "error" in short or "error" in long:
        return {"whole_process_peak": "n/a: a run failed"}
    out["whole_process_peak"] = _ratio(
        long["whole_process_peak_kb"], short["whole_process_peak_kb"]
    )
    rs, rl = short["rss_kb"], long["rss_kb"]
    assert isinstance(rs, Mapping) and isinstance(rl, Mapping)
    for key in ("run_peak", "dataset", "setup_peak"):
        out[key] = (
            _ratio(rl[key], rs[key])
            if rl.get(key) and rs.get(key)
            else "n/a: the peak could not be reset after the set-up"
        )
    return out


def _ratio(a: object, b: object) -> float:
    return float(a) / float(b)  # type: ignore[arg-type]


def _mb(kb: object) -> str:
    return f"{float(kb) / 1024:.0f}" if isinstance(kb, int | float) else "n/a"


def table(runs: Sequence[Mapping[str, object]]) -> list[str]:
    """The printed table: one row a run, numbers or ``n/a``, never ``nan``."""
    head = (
        f"{'minutes':>7} {'frames':>7} {'est.':>7} {'fail':>4} {'APE(m)':>7} {'fps':>6} "
        f"{'imports':>8} {'input':>6} {'setup pk':>8} {'run pk':>7} {'process pk':>10} "
        f"{'growth kB/min':>13}"
    )
    lines = [head, "-" * len(head)]
    for r in runs:
        if "error" in r:
            lines.append(f"{float(r['minutes']):>7g} {r['error']}")  # type: ignore[arg-type]
            continue
        rss = r["rss_kb"]
        assert isinstance(rss, Mapping)
        ape = r["ape_se3_m"]
        g = growth_kb_per_min(r["samples"])  # type: ignore[arg-type]
        lines.append(
            f"{float(r['minutes']):>7g} {r['frames']:>7} {r['frames_with_estimate']:>7} "  # type: ignore[arg-type]
            f"{r['failures']:>4} {f'{ape:.3f}' if isinstance(ape, float) else 'n/a':>7} "
            f"{float(r['frames_per_s']):>6.1f} {_mb(rss['imports']):>8} {_mb(rss['dataset']):>6} "  # type: ignore[arg-type]
            f"{_mb(rss['setup_peak']):>8} {_mb(rss['run_peak']):>7} "
            f"{_mb(r['whole_process_peak_kb']):>10} {f'{g:.0f}' if g is not None else 'n/a':>13}"
        )
    for r in runs:
        mp = r.get("map")
        if isinstance(mp, Mapping) and mp["keyframes"]:
            lines.append(
                f"{float(r['minutes']):g} min: the map at the end {mp['keyframes']} keyframes "  # type: ignore[arg-type]
                f"({mp['good_keyframes']} not culled), {mp['points']} points, its arrays "
                f"{mp['nbytes'] / 1e6:.1f} MB ({mp['nbytes'] / 1e3 / mp['keyframes']:.1f} kB a keyframe)"
            )
    return lines


def _pin(core: int) -> None:
    """One core, before numpy, OpenCV or GTSAM load (their thread pools size themselves from
    the affinity mask, which a child inherits); one thread for the BLAS libraries."""
    try:
        os.sched_setaffinity(0, {core})
    except (ValueError, OSError):
        _fail(f"--core {core}: not one of this machine's cores {sorted(os.sched_getaffinity(0))}")
    for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[v] = "1"


def _parse() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description="VIO or SLAM memory over a long run, one core")
    parser.add_argument("--minutes", type=float, nargs="+", default=[3.0, 30.0])
    parser.add_argument("--odometry", choices=("vio", "slam"), default="vio")
    parser.add_argument("--sequence", default="room_easy")
    parser.add_argument("--rig", default="euroc_mono")
    parser.add_argument("--sensors", choices=("ideal", "realistic"), default="ideal")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--every", type=int, default=200)
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--core", type=int, default=0)
    parser.add_argument("--child", type=float, default=None, help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/vio_memory.json"))
    args = parser.parse_args()
    if args.sequence not in SEQUENCES:
        _fail(f"--sequence {args.sequence!r}: one of {', '.join(SEQUENCES)}")
    for minutes in args.minutes if args.child is None else [args.child]:
        if not 0.5 <= minutes <= 30.0:
            _fail(f"--minutes {minutes:g}: from 0.5 to 30 (a sequence is at most 1800 s)")
    if not 0.25 <= args.scale <= 1.0:
        _fail(f"--scale {args.scale:g}: from 0.25 to 1 (of the rig's image size)")
    if args.every < 1:
        _fail(f"--every must be at least 1, got {args.every}")
    return args


def main() -> None:
    args = _parse()
    _pin(args.core)
    if args.child is not None:
        from quadnav.errors import QuadnavError

        try:
            print(RESULT_TAG + json.dumps(_child(args)), flush=True)
        except QuadnavError as exc:
            _fail(str(exc))
        return
    print(f"{args.odometry.upper()} memory on {args.sequence}'s motion, rig {args.rig}, {args.sensors} sensors, "
          f"seed {args.seed}, one core (affinity {sorted(os.sched_getaffinity(0))}); RSS in MB",
          flush=True)  # fmt: skip
    runs: list[dict[str, object]] = []
    for minutes in sorted(args.minutes):
        runs.append(_run_child(args, minutes))
        print(table(runs[-1:])[2], flush=True)  # each run's row as it ends; the JSON so far
        result = _result(args, runs)
    print("\n".join(table(runs)))
    r = result.get("ratios_longest_over_shortest")
    if isinstance(r, Mapping):
        print("longest / shortest: " + ", ".join(
            f"{k} {v:.2f}" if isinstance(v, float) else f"{k} {v}" for k, v in r.items()
        ))  # fmt: skip
    print(f"wrote {args.out}")


def _result(args: argparse.Namespace, runs: list[dict[str, object]]) -> dict[str, object]:
    """The JSON of the runs so far, written (a stopped long run leaves the shorter ones')."""
    from quadnav.io.run_folder import write_text

    result: dict[str, object] = {
        "benchmark": "vio_memory", "odometry": args.odometry, "python": platform.python_version(),
        "sequence": args.sequence, "rig": args.rig, "sensors": args.sensors, "seed": args.seed,
        "core": args.core, "every_frames": args.every, "scale": args.scale,
        "malloc_mmap_threshold_bytes": MMAP_THRESHOLD, "runs": runs,
    }  # fmt: skip
    if len(runs) >= 2:
        result["ratios_longest_over_shortest"] = ratios(runs[0], runs[-1])
    write_text(args.out, json.dumps(result, indent=2) + "\n")
    return result


if __name__ == "__main__":
    main()
