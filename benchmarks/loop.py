"""Loop closure's cost (issue 23): what ``--loop`` costs the odometry, and its map on disk and in
memory.

1. ``quadnav vio DATASET --stereo --no-video`` with and without ``--loop``, each as a whole
   process, the two taking turns ``--repeats`` times (a busy spell of the shared machine falls
   on both): the estimator's frames/s (the run's ``timing.json``: every ``push`` and
   ``keyframes`` of the odometry, loop closure's work included), the process's wall time (what
   the user feels: start-up, reading images, the pose graph's worker, metrics, plots and report)
   and its CPU time (user + system of the process and its children: steadier than wall time on
   a shared machine), best of the repeats; and memory: the largest single process's peak
   resident set (``ru_maxrss`` from ``wait4``, as ``/usr/bin/time -v`` gives it) and the peak
   of the process tree's summed resident set and proportional set (``/proc/<pid>/smaps_rollup``
   ``Rss``, ``Pss``, sampled every 0.1 s: the pose graph's worker is a process of its own), the
   main process's own peak ``Pss`` and its children's (the worker), and the children's CPU time
   (as last sampled). The ratio loop/off of each.

2. The map (``--save-map``/``--load-map``, :mod:`quadnav.io.loop_map`): a real map (``--map``,
   or the one ``quadnav vio DATASET --stereo --loop --no-video --save-map`` makes first) has its
   keyframes tiled, with new indices and times, into a synthetic map of ``--keyframes``
   keyframes shaped like real ones (keypoints, landmarks, words, direct index; its loops tiled
   with them). Saved and loaded (with the vocabulary and camera checks a run makes) ``--repeats``
   times: best and worst time of each; the start of ``--load-map`` in a fresh process (the load,
   then building a ``LoopClosure`` on the map); the round trip (save, load, save again: every
   array of the two files bitwise equal, dtype and shape too, and the headers equal); bytes on
   disk per keyframe, per array; what two lossless changes of the format would give (each
   integer array in the narrowest integer type that holds its values; ``np.savez_compressed``),
   not made here;
   and loop closure's memory per keyframe of a loaded map: a ``LoopClosure`` (pose graph in a
   thread, so that the process holds it all) built on the map loaded from disk, the map's own
   object then dropped, against one built without a map: the Python heap it keeps
   (``tracemalloc``: numpy's arrays included) and the resident set's growth, per keyframe; and
   the sum of ``nbytes`` of the arrays it keeps per keyframe (keyframe records, bags of words,
   direct indices, the database's inverted index). Then the map of a ``--minutes`` run at the
   keyframe rate of part 1's loop run (its keyframes / the dataset's duration): its size, save
   and load times measured on a tiled map of that many keyframes, its memory extrapolated from
   the per-keyframe figures.

    python benchmarks/loop.py DATASET [--map DIR] [--repeats 3] [--keyframes 1000]
        [--minutes 30] [--skip-runs --map DIR --keyframes-per-s X]
        [--out benchmarks/results/loop.json]

DATASET: a stereo dataset that revisits, e.g. ``quadnav dataset make hall_laps --rig euroc
--seed 0 --out data/hall_laps_s0``. ``--skip-runs``: part 2 alone, on a saved map and a given
keyframe rate.
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import json
import multiprocessing
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
import tracemalloc
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import cast

import numpy as np

from quadnav.errors import QuadnavError
from quadnav.io.datasets import open_dataset
from quadnav.io.loop_map import load_loop_map, save_loop_map
from quadnav.io.run_folder import write_text
from quadnav.loop import LoopClosure, LoopConfig
from quadnav.loop.map import LoopMap, MapCamera, MapKeyframe
from quadnav.odometry import VisualOdometry
from quadnav.place.vocabulary import default_vocabulary
from quadnav.posegraph.background import Executor
from quadnav.posegraph.types import LoopEdge
from quadnav.rig import CameraSpec

LOAD_LIMIT_S = 2.0
SAMPLE_S = 0.1
MB = 1024 * 1024


def _fail(message: str) -> None:
    """A bad input: one line naming the option or path, exit code 2 (as the CLI does)."""
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


# -- part 1: the odometry with and without loop closure -----------------------------------------


def _children() -> dict[int, list[int]]:
    """Every process's children (``/proc/<pid>/stat``'s parent field)."""
    kids: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            stat = Path(f"/proc/{d}/stat").read_text()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        kids.setdefault(ppid, []).append(int(d))
    return kids


def _cpu_s(pid: int) -> float:
    """User + system time of ``pid`` so far (s), 0 if it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def tree_sample(root: int) -> tuple[dict[str, int], dict[int, float]]:
    """``Rss`` and ``Pss`` (kB) now of ``root`` (``root_rss``, ``root_pss``) and of its
    descendants summed (``rest_rss``, ``rest_pss``), and each descendant's CPU time so far."""
    kids, todo = _children(), [root]
    mem = {"root_rss": 0, "root_pss": 0, "rest_rss": 0, "rest_pss": 0}
    cpu = {}
    while todo:
        pid = todo.pop()
        todo.extend(kids.get(pid, []))
        who = "root" if pid == root else "rest"
        if pid != root:
            cpu[pid] = _cpu_s(pid)
        try:
            text = Path(f"/proc/{pid}/smaps_rollup").read_text()
        except OSError:
            continue
        for line in text.splitlines():
            key, _, rest = line.partition(":")
            if key in ("Rss", "Pss"):
                mem[f"{who}_{key.lower()}"] += int(rest.split()[0])
    return mem, cpu


def run_measured(cmd: list[str]) -> dict[str, float]:
    """Wall and CPU time (s) of ``cmd`` as a whole process (CPU: it and its children), the
    largest single process's peak resident set, and sampled: the peaks of the tree's summed
    ``Rss`` and ``Pss``, of the process's own ``Pss`` and of its descendants' (MB), and the
    descendants' CPU time (s, as last sampled before each ended)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    peak = {"tree_rss": 0, "tree_pss": 0, "root_pss": 0, "rest_pss": 0}
    child_cpu: dict[int, float] = {}
    done = threading.Event()

    def sample() -> None:
        while not done.wait(SAMPLE_S):
            m, cpu = tree_sample(proc.pid)
            now = {"tree_rss": m["root_rss"] + m["rest_rss"], "tree_pss": m["root_pss"] + m["rest_pss"],
                   "root_pss": m["root_pss"], "rest_pss": m["rest_pss"]}  # fmt: skip
            for k, v in now.items():
                peak[k] = max(peak[k], v)
            for pid, c in cpu.items():
                child_cpu[pid] = max(child_cpu.get(pid, 0.0), c)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    assert proc.stderr is not None
    err = proc.stderr.read()  # until the process closes it (it exits)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    done.set()
    sampler.join()
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{err.decode(errors='replace')[-2000:]}")
    return {
        "wall_s": wall,
        "cpu_s": usage.ru_utime + usage.ru_stime,
        "max_rss_mb": usage.ru_maxrss / 1024,
        "tree_rss_peak_mb": peak["tree_rss"] / 1024,
        "tree_pss_peak_mb": peak["tree_pss"] / 1024,
        "main_pss_peak_mb": peak["root_pss"] / 1024,
        "children_pss_peak_mb": peak["rest_pss"] / 1024,
        "children_cpu_s": sum(child_cpu.values()),
    }


def _run_folder(out: Path) -> Path:
    (run,) = [p for p in out.iterdir() if p.is_dir()]
    return run


def vio_run(dataset: Path, loop: bool, save_map: Path | None = None) -> dict[str, float]:
    """One ``quadnav vio DATASET --stereo --no-video`` (``--loop``) measured."""
    quadnav = str(Path(sys.executable).with_name("quadnav"))
    with tempfile.TemporaryDirectory() as out:
        cmd = [quadnav, "vio", str(dataset), "--stereo", "--no-video", "--out", out]
        cmd += ["--loop"] if loop else []
        cmd += ["--save-map", str(save_map)] if save_map is not None else []
        r = run_measured(cmd)
        run = _run_folder(Path(out))
        timing = json.loads((run / "timing.json").read_text())
        r |= {k: float(timing[k]) for k in ("frames", "estimator_s", "frames_per_s")}
        r["run_wall_s"] = float(timing["wall_s"])
        if loop:
            stats = json.loads((run / "loop.json").read_text())
            r |= {"keyframes": stats["keyframes"], "loops": stats["accepted"]}
    return r


#: the figures compared, each best (lowest, or highest for frames/s) of the repeats
FIGURES = {
    "frames_per_s": ("estimator frames/s", max),
    "wall_s": ("whole process wall s", min),
    "cpu_s": ("whole process CPU s", min),
    "max_rss_mb": ("peak RSS, largest process MB", min),
    "tree_rss_peak_mb": ("peak RSS, process tree MB", min),
    "tree_pss_peak_mb": ("peak PSS, process tree MB", min),
    "main_pss_peak_mb": ("peak PSS, main process MB", min),
    "children_pss_peak_mb": ("peak PSS, child processes MB", min),
    "children_cpu_s": ("CPU s of child processes", min),
}


def odometry_cost(dataset: Path, repeats: int) -> dict[str, object]:
    """Part 1: the runs with loop closure off and on, taking turns."""
    runs: dict[str, list[dict[str, float]]] = {"off": [], "on": []}
    for r in range(repeats):
        for mode in ("off", "on") if r % 2 == 0 else ("on", "off"):
            runs[mode].append(vio_run(dataset, mode == "on"))
            x = runs[mode][-1]
            print(f"  run {r + 1} loop {mode:<3}: {x['frames_per_s']:.1f} frames/s, "
                  f"{x['wall_s']:.1f} s wall, {x['cpu_s']:.1f} s CPU, "
                  f"{x['tree_pss_peak_mb']:.0f} MB PSS", flush=True)  # fmt: skip
    best = {
        mode: {k: float(pick(x[k] for x in rs)) for k, (_, pick) in FIGURES.items()}
        for mode, rs in runs.items()
    }
    on = runs["on"][0]
    return {"runs": runs, "best": best, "keyframes": on["keyframes"], "loops": on["loops"],
            "frames": on["frames"]}  # fmt: skip


def _print_cost(dataset: Path, cost: dict[str, object], repeats: int) -> None:
    best = cast(dict[str, dict[str, float]], cost["best"])
    print(f"\nquadnav vio {dataset.name} --stereo --no-video, loop closure off and on, best of "
          f"{repeats} ({cost['frames']:.0f} frames, {cost['keyframes']} keyframes, "
          f"{cost['loops']} loops)")  # fmt: skip
    print(f"{'':<30}{'off':>9}{'on':>9}{'on/off':>8}")
    for k, (name, _) in FIGURES.items():
        off, on = best["off"][k], best["on"][k]
        ratio = f"{on / off:>8.2f}" if off > 0 else f"{'-':>8}"
        print(f"{name:<30}{off:>9.1f}{on:>9.1f}{ratio}")
    n = float(cost["keyframes"])  # type: ignore[arg-type]
    cpu = best["on"]["cpu_s"] - best["off"]["cpu_s"]
    main = (best["on"]["main_pss_peak_mb"] - best["off"]["main_pss_peak_mb"]) * 1024
    print(f"on - off: CPU {cpu:.1f} s ({1e3 * cpu / n:.0f} ms per keyframe, the worker's start "
          f"included); main process's peak PSS {main / 1024:.1f} MB ({main / n:.0f} kB per "
          "keyframe, the vocabulary included)")  # fmt: skip


# -- part 2: the map ----------------------------------------------------------------------------


def tiled_map(real: LoopMap, n: int) -> LoopMap:
    """``n`` keyframes: ``real``'s over and over, indices 0..n-1, each tile's times after the
    last's, and ``real``'s loops with each tile."""
    kfs = real.keyframes
    if not kfs:
        raise QuadnavError("the map has no keyframes to tile")
    t = [k.record.t_ns for k in kfs]
    span = t[-1] - t[0] + (t[-1] - t[0]) // max(len(t) - 1, 1)
    pos = {k.record.index: i for i, k in enumerate(kfs)}
    out = []
    for k in range(n):
        tile, src = divmod(k, len(kfs))
        rec = dataclasses.replace(src_rec := kfs[src].record, index=k,
                                  t_ns=src_rec.t_ns + tile * span)  # fmt: skip
        out.append(MapKeyframe(record=rec, bow=kfs[src].bow, direct=kfs[src].direct))
    loops = []
    for tile in range(-(-n // len(kfs))):
        for e in real.loops:
            old, new = pos[e.old] + tile * len(kfs), pos[e.new] + tile * len(kfs)
            if new < n:
                loops.append(dataclasses.replace(e, old=old, new=new))
    return LoopMap(keyframes=tuple(out), loops=tuple(cast(list[LoopEdge], loops)),
                   camera=real.camera, vocabulary=real.vocabulary)  # fmt: skip


def _npz(folder: Path) -> dict[str, np.ndarray]:
    with np.load(folder / "keyframes.npz", allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def bitwise_equal(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> list[str]:
    """The names of the arrays that differ in name, dtype, shape or bytes."""
    return [
        k for k in sorted(set(a) | set(b))
        if k not in a or k not in b or a[k].dtype != b[k].dtype or a[k].shape != b[k].shape
        or a[k].tobytes() != b[k].tobytes()
    ]  # fmt: skip


def _folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.iterdir())


def narrowest(a: np.ndarray) -> np.ndarray:
    """An integer array in the narrowest integer type that holds its values (others as they are)."""
    if a.dtype.kind not in "iu" or a.size == 0:
        return a
    lo, hi = int(a.min()), int(a.max())
    for t in (np.uint8, np.int8, np.uint16, np.int16, np.uint32, np.int32):
        if np.iinfo(t).min <= lo and hi <= np.iinfo(t).max:
            return a.astype(t)
    return a


def format_options(folder: Path, tmp: Path) -> dict[str, dict[str, float]]:
    """The map's arrays as saved, with integers narrowed, compressed, and both: bytes, and the
    time to write them and to read them back (``np.savez``/``np.load``, once)."""
    arrays = _npz(folder)
    narrow = {k: narrowest(v) for k, v in arrays.items()}
    out = {}
    for name, arrs, save in (("as saved", arrays, np.savez), ("integers narrowed", narrow, np.savez),
                             ("savez_compressed", arrays, np.savez_compressed),
                             ("narrowed + compressed", narrow, np.savez_compressed)):  # fmt: skip
        f = tmp / f"{name.replace(' ', '_')}.npz"
        t0 = time.perf_counter()
        save(f, **arrs)  # type: ignore[operator]
        t1 = time.perf_counter()
        _ = {k: v.copy() for k, v in np.load(f, allow_pickle=False).items()}
        t2 = time.perf_counter()
        out[name] = {"bytes": f.stat().st_size, "write_s": t1 - t0, "read_s": t2 - t1}
        f.unlink()
    return out


def time_save_load(m: LoopMap, folder: Path, repeats: int, camera: MapCamera) -> dict[str, float]:
    """Best and worst time of ``repeats`` saves and loads (the load with a run's checks)."""
    vocabulary = m.vocabulary
    saves, loads = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        save_loop_map(folder, m)
        saves.append(time.perf_counter() - t0)
        gc.collect()
        t0 = time.perf_counter()
        load_loop_map(folder, vocabulary=vocabulary, camera=camera)
        loads.append(time.perf_counter() - t0)
        gc.collect()
    return {"save_best_s": min(saves), "save_worst_s": max(saves),
            "load_best_s": min(loads), "load_worst_s": max(loads)}  # fmt: skip


def _rss_kb() -> int:
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") // 1024


def _closer(
    camera: CameraSpec, loop_map: LoopMap | None, executor: Executor = "thread"
) -> LoopClosure:
    # the odometry is only driven by push(), which this does not call
    no_odometry = cast(VisualOdometry, None)
    return LoopClosure(no_odometry, camera, config=LoopConfig(executor=executor), loop_map=loop_map)


def closer_start(folder: Path, dataset: Path, repeats: int) -> dict[str, float]:
    """Best of ``repeats``: from a saved map to a loop closure ready on it, as ``--load-map``
    starts (the vocabulary already loaded): ``load_s`` (:func:`load_loop_map` with its
    checks) and ``build_s`` (the ``LoopClosure``: the map's keyframes into the place database
    and, held fixed, into the pose graph, which solves nothing until a loop). Run in a fresh
    process."""
    camera = open_dataset(dataset).rig.camera("cam0")
    vocabulary = default_vocabulary().fingerprint
    best = {"load_s": np.inf, "build_s": np.inf}
    for _ in range(repeats):
        gc.collect()
        t0 = time.perf_counter()
        m = load_loop_map(folder, vocabulary=vocabulary, camera=MapCamera.of(camera))
        t1 = time.perf_counter()
        closer = _closer(camera, m, "process")
        t2 = time.perf_counter()
        closer.close()
        del m, closer
        for k, v in (("load_s", t1 - t0), ("build_s", t2 - t1)):
            best[k] = min(best[k], v)
    return {k: float(v) for k, v in best.items()}


def kept_nbytes(closer: LoopClosure) -> dict[str, int]:
    """The bytes of the arrays a loop closure keeps: its keyframe records, the database's bags of
    words, direct indices and inverted index (the postings' pools at their capacity)."""
    recs = list(closer._by_index.values())
    db = closer.detector.database
    fields = ("ids", "uv_px", "xy", "descriptors", "described", "landmark_ids", "landmarks_W",
              "cov_pose")  # fmt: skip
    out = {f"record.{f}": sum(int(getattr(r, f).nbytes) for r in recs if getattr(r, f) is not None)
           for f in fields}  # fmt: skip
    bows, direct, post = db._bows, db._direct, db._postings
    out["bow.words"] = sum(b.words.nbytes for b in bows)
    out["bow.weights"] = sum(b.weights.nbytes for b in bows)
    out["direct"] = sum(d.nodes.nbytes + d.offsets.nbytes + d.features.nbytes for d in direct)
    out["inverted index (pool capacity)"] = post.entries.nbytes + post.weights.nbytes
    out["inverted index (used)"] = 8 * int(post.size.sum())
    return out


def closer_memory(folder: Path, dataset: Path) -> dict[str, object]:
    """What a loop closure keeps of a map loaded from ``folder``, against one without a map
    (its camera: ``dataset``'s cam0). Run in a fresh process (:func:`fresh_process`): the
    resident set's growth means little in one that has freed memory before."""
    camera = open_dataset(dataset).rig.camera("cam0")
    vocabulary = default_vocabulary().fingerprint
    tracemalloc.start()
    held: list[LoopClosure] = []

    def build(loop_map_folder: Path | None) -> tuple[int, int]:
        gc.collect()
        py0, rss0 = tracemalloc.get_traced_memory()[0], _rss_kb()
        m = None
        if loop_map_folder is not None:
            m = load_loop_map(loop_map_folder, vocabulary=vocabulary, camera=MapCamera.of(camera))
        held.append(_closer(camera, m))
        held[-1].graph.wait()
        del m
        gc.collect()
        return tracemalloc.get_traced_memory()[0] - py0, (_rss_kb() - rss0) * 1024

    _closer(camera, None).close()  # the vocabulary and the graph's imports, once
    empty_py, empty_rss = build(None)
    map_py, map_rss = build(folder)
    tracemalloc.stop()
    nbytes = kept_nbytes(held[-1])
    for c in held:
        c.close()
    voc = default_vocabulary()
    fields = [getattr(voc, f.name) for f in dataclasses.fields(voc)]
    voc_bytes = sum(int(v.nbytes) for v in fields if isinstance(v, np.ndarray))
    return {"python_heap_bytes": map_py - empty_py, "rss_bytes": map_rss - empty_rss,
            "nbytes": nbytes, "without_map_python_heap_bytes": empty_py,
            "vocabulary_nbytes": voc_bytes}  # fmt: skip


def fresh_process(fn: Callable[..., dict[str, object]], *args: object) -> dict[str, object]:
    """``fn(*args)`` in a spawned process of its own."""
    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(1, mp_context=spawn) as pool:
        return pool.submit(fn, *args).result()


def map_cost(real: LoopMap, n: int, repeats: int, dataset: Path, tmp: Path) -> dict[str, object]:
    """Part 2 for a tiled map of ``n`` keyframes."""
    m = tiled_map(real, n)
    camera = open_dataset(dataset).rig.camera("cam0")
    a, b = tmp / "a", tmp / "b"
    times = time_save_load(m, a, repeats, MapCamera.of(camera))
    start = fresh_process(closer_start, a, dataset, repeats)
    loaded = load_loop_map(a, vocabulary=m.vocabulary, camera=MapCamera.of(camera))
    save_loop_map(b, loaded)
    differ = bitwise_equal(_npz(a), _npz(b))
    differ += bitwise_equal(m.to_arrays()[1], loaded.to_arrays()[1])  # type: ignore[arg-type]
    heads_equal = (a / "map.json").read_text() == (b / "map.json").read_text()
    arrays = _npz(a)
    out: dict[str, object] = {
        "keyframes": n, "loops": len(m.loops), **times, "closer_start": start,
        "round_trip_exact": not differ and heads_equal, "round_trip_differ": differ,
        "disk_bytes": _folder_bytes(a),
        "array_bytes_per_keyframe": {k: v.nbytes / n for k, v in arrays.items()},
        "format_options": format_options(a, tmp),
    }  # fmt: skip
    del m, loaded, arrays
    return out


def _print_map(r: dict[str, object], memory: dict[str, object] | None) -> None:
    n = int(r["keyframes"])  # type: ignore[call-overload]
    print(f"\nmap of {n} keyframes ({r['loops']} loops), tiled from a real one")
    print(f"  save {r['save_best_s']:.2f} s best, {r['save_worst_s']:.2f} worst; load "
          f"{r['load_best_s']:.2f} s best, {r['load_worst_s']:.2f} worst "
          f"(< {LOAD_LIMIT_S:.0f} s: {'yes' if r['load_worst_s'] < LOAD_LIMIT_S else 'NO'})")  # type: ignore[operator]  # fmt: skip
    st = cast(dict[str, float], r["closer_start"])
    print(f"  to a loop closure on it (--load-map's start, best): load {st['load_s']:.2f} s, "
          f"build {st['build_s']:.2f} s")  # fmt: skip
    print(
        f"  round trip save-load-save bitwise exact: {'yes' if r['round_trip_exact'] else 'NO'}"
        + (f" (differ: {r['round_trip_differ']})" if r["round_trip_differ"] else "")
    )
    disk = int(r["disk_bytes"])  # type: ignore[call-overload]
    print(f"  on disk {disk / MB:.1f} MB, {disk / n / 1024:.1f} kB per keyframe")
    per = cast(dict[str, float], r["array_bytes_per_keyframe"])
    top = sorted(per.items(), key=lambda kv: -kv[1])[:8]
    print("  largest arrays, B/keyframe: " + ", ".join(f"{k} {v:.0f}" for k, v in top))
    opts = cast(dict[str, dict[str, float]], r["format_options"])
    print(
        "  keyframes.npz saved otherwise (a proposal, not done): kB/keyframe, ratio, write s, read s"
    )
    for k, v in opts.items():
        print(f"    {k:<24}{v['bytes'] / n / 1024:>6.1f}{v['bytes'] / opts['as saved']['bytes']:>6.2f}"
              f"{v['write_s']:>7.2f}{v['read_s']:>7.2f}")  # fmt: skip
    if memory is not None:
        kept = cast(dict[str, int], memory["nbytes"])
        py, rss = int(memory["python_heap_bytes"]), int(memory["rss_bytes"])  # type: ignore[call-overload]
        arr = sum(v for k, v in kept.items() if k != "inverted index (used)")
        print(f"  loop closure holding it (RAM per keyframe): Python heap (tracemalloc) "
              f"{py / n / 1024:.1f} kB, RSS growth {rss / n / 1024:.1f} kB, its arrays' nbytes "
              f"{arr / n / 1024:.1f} kB")  # fmt: skip
        print("    arrays, B/keyframe: " + ", ".join(f"{k} {v / n:.0f}" for k, v in kept.items()))
        fixed, voc = int(memory["without_map_python_heap_bytes"]), int(memory["vocabulary_nbytes"])  # type: ignore[call-overload]
        print(f"  fixed: a loop closure without a map {fixed / MB:.1f} MB (Python heap), the "
              f"vocabulary (loaded once) {voc / MB:.1f} MB")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description="loop closure's cost: frame rate, memory, map")
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--map", type=Path, default=None, help="a saved map (default: made)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--keyframes", type=int, default=1000)
    parser.add_argument("--minutes", type=float, default=30.0)
    parser.add_argument("--skip-runs", action="store_true", help="part 2 only (needs --map "
                        "and --keyframes-per-s)")  # fmt: skip
    parser.add_argument("--keyframes-per-s", type=float, default=None)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/loop.json"))
    args = parser.parse_args()
    if not args.dataset.exists():
        _fail(f"DATASET {args.dataset}: no such file or folder")
    if args.map is not None and not args.map.is_dir():
        _fail(f"--map {args.map}: no such folder")
    for option, value in (("--repeats", args.repeats), ("--keyframes", args.keyframes)):
        if value < 1:
            _fail(f"{option} must be at least 1, got {value}")
    if not 0 < args.minutes <= 600:
        _fail(f"--minutes must be in (0, 600], got {args.minutes}")
    if args.skip_runs and (args.map is None or args.keyframes_per_s is None):
        _fail("--skip-runs needs --map and --keyframes-per-s")
    if args.keyframes_per_s is not None and not 0 < args.keyframes_per_s <= 1000:
        _fail(f"--keyframes-per-s must be in (0, 1000], got {args.keyframes_per_s}")
    try:
        _measure(args)
    except QuadnavError as exc:
        _fail(str(exc))


def _measure(args: argparse.Namespace) -> None:
    ds = open_dataset(args.dataset)
    camera = ds.rig.camera("cam0")
    result: dict[str, object] = {"benchmark": "loop", "python": platform.python_version(),
                                 "dataset": str(args.dataset), "duration_s": ds.duration_s,
                                 "repeats": args.repeats}  # fmt: skip
    if args.skip_runs:
        kf_per_s = float(args.keyframes_per_s)
    else:
        cost = odometry_cost(args.dataset, args.repeats)
        _print_cost(args.dataset, cost, args.repeats)
        kf_per_s = float(cost["keyframes"]) / ds.duration_s  # type: ignore[arg-type]
        result["odometry"] = cost
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        map_folder = args.map
        if map_folder is None:
            map_folder = tmp / "real"
            print(f"\nmaking a map: quadnav vio {args.dataset.name} --stereo --loop --save-map")
            vio_run(args.dataset, True, save_map=map_folder)
        vocabulary = default_vocabulary().fingerprint
        real = load_loop_map(map_folder, vocabulary=vocabulary, camera=MapCamera.of(camera))
        result["real_map"] = {"folder": str(map_folder), "keyframes": len(real.keyframes),
                              "disk_bytes": _folder_bytes(map_folder)}  # fmt: skip
        one = map_cost(real, args.keyframes, args.repeats, args.dataset, tmp)
        memory = fresh_process(closer_memory, tmp / "a", args.dataset)
        _print_map(one, memory)
        n_long = round(kf_per_s * 60 * args.minutes)
        long = map_cost(real, n_long, args.repeats, args.dataset, tmp)
        per_kf_ram = int(memory["python_heap_bytes"]) / args.keyframes  # type: ignore[call-overload]
        print(f"\na {args.minutes:.0f}-minute run at {kf_per_s:.2f} keyframes/s "
              f"({args.dataset.name}'s loop run): {n_long} keyframes")  # fmt: skip
        _print_map(long, None)
        print(f"  loop closure's RAM for it (per-keyframe Python heap above x {n_long}): "
              f"{per_kf_ram * n_long / MB:.0f} MB")  # fmt: skip
    result |= {"keyframes_per_s": kf_per_s, "map": one, "closer_memory": memory,
               "long_run": {"minutes": args.minutes, **long,
                            "closer_ram_bytes_extrapolated": per_kf_ram * n_long}}  # fmt: skip
    write_text(args.out, json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
