"""quadnav's SLAM side by side with ORB-SLAM3 on the same datasets, in one run (issue 24):
stereo (``quadnav slam DATASET``; ORB-SLAM3 ``stereo`` through ``../shared/peers/orbslam3/``'s
``make_settings.py`` and ``run_orb.py``) on EuRoC-rig folders, and RGB-D (the same
``quadnav slam DATASET``, the rig read from the folder; ORB-SLAM3 ``RGBD`` through
``benchmarks/orb_rgbd.py``, our runner in its venv: the peer's has no RGB-D mode) on folders
``quadnav dataset make WORLD --rig rgbd`` writes. A system runs only on the datasets of its kind.
ORB-SLAM3 unpaced (its speed) or ``*_paced`` (it sleeps to the camera rate, as its examples do:
its mapping threads get the time), each a subprocess with a timeout; ``--repeats`` runs each,
median reported (``--quadnav-repeats``: quadnav's, which is deterministic).

Scored by the same code (``quadnav.eval``'s ``evaluate_pair``) against ``groundtruth.tum``:

- **causal**: the pose each frame got when it was tracked (quadnav ``estimate.tum``,
  ORB-SLAM3 ``orb_online.tum``): APE RMSE after SE(3) and Sim(3) alignment, Sim(3)'s scale,
  the share of camera frames with a pose;
- **final**: ORB-SLAM3's saved trajectory (``orb_saved.tum``: every frame re-expressed through
  its reference keyframe's final pose) against ours made the same way: each frame of
  ``estimate.tum`` carried by the newest keyframe not after it from where that keyframe was
  tracked to where the final map has it (``keyframes_final.tum``; ORB-SLAM3 keeps each frame's
  own reference keyframe, we take the newest: an approximation), or, from a quadnav that writes
  it, ``estimate_final.tum`` (each frame through its own reference keyframe, as ORB-SLAM3);
- **keyframes**: the final map's keyframes (ours ``keyframes_final.tum``, ORB-SLAM3
  ``orb_kf_euroc.txt``), SE(3);
- losses (ours: failures; ORB-SLAM3: OK to lost), ORB-SLAM3's map resets, new maps and loops
  (its log; ours: relocalizations and loops, from its events), tracking ms a frame (ours: the
  estimator's time a frame, ``timing.json``, local mapping included since it runs inline;
  ORB-SLAM3: its mean ``track_*`` call, ``stats.json``, local mapping in its own thread), the
  whole process's wall time. The 1-min load average before each run is recorded.

``--no-loop``: both without loop closing (quadnav ``--no-loop``, ORB-SLAM3 ``loopClosing: 0``).

Without the peer's venv (``--orb-venv``: ``bin/python`` and ``orbvoc.txt``) one line says so and
quadnav's side runs alone.

    python benchmarks/slam_peer.py DATASET [DATASET ...] [--systems quadnav_stereo,orb_stereo,
        orb_stereo_paced,quadnav_rgbd,orb_rgbd,orb_rgbd_paced] [--repeats 3]
        [--quadnav-repeats 3] [--no-loop] [--timeout 900] [--orb-venv ../orb-venv]
        [--orb-dir ../shared/peers/orbslam3] [--keep DIR] [--out benchmarks/results/slam_peer.json]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import orb_peer
from orb_peer import (
    OrbPeer,
    available,
    camera_T_C_B,
    check_arguments,
    coverage,
    dataset_record,
    each_dataset,
    fail,
    frames,
    last_line,
    log_counts,
    markdown_table,
    orb_failure,
    peer_parser,
    read_orb_euroc,
    repeated,
    score,
    write_results,
)
from orb_peer import run_process as _run
from quadnav.errors import QuadnavError
from quadnav.eval.na import Metric, median_or_na, na
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.run_folder import read_run_status
from quadnav.io.trajectory_io import read_tum

HERE = Path(__file__).resolve().parent

#: name -> (label, kind, the datasets' kind, paced)
SYSTEMS: dict[str, tuple[str, str, str, bool]] = {
    "quadnav_stereo": ("quadnav SLAM stereo", "quadnav", "stereo", False),
    "orb_stereo": ("ORB-SLAM3 stereo", "orb", "stereo", False),
    "orb_stereo_paced": ("ORB-SLAM3 stereo, paced", "orb", "stereo", True),
    "quadnav_rgbd": ("quadnav SLAM RGB-D", "quadnav", "rgbd", False),
    "orb_rgbd": ("ORB-SLAM3 RGB-D", "orb", "rgbd", False),
    "orb_rgbd_paced": ("ORB-SLAM3 RGB-D, paced", "orb", "rgbd", True),
}

#: (key, column heading, format)
ACCURACY_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("ape_se3_m", "ATE SE(3) causal (m)", ".3f"),
    ("final_ape_se3_m", "ATE SE(3) final (m)", ".3f"),
    ("kf_ape_se3_m", "keyframes ATE SE(3) (m)", ".3f"),
    ("ape_sim3_m", "ATE Sim(3) causal (m)", ".3f"),
    ("sim3_scale", "scale", ".3f"),
    ("coverage_pct", "frames with pose (%)", ".0f"),
    ("final_coverage_pct", "frames in final (%)", ".0f"),
)
COUNT_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("losses", "losses", ".0f"),
    ("relocalizations", "relocalizations", ".0f"),
    ("resets", "map resets", ".0f"),
    ("new_maps", "new maps", ".0f"),
    ("loops", "loops", ".0f"),
    ("keyframes", "keyframes (final)", ".0f"),
    ("track_ms", "tracking ms/frame", ".1f"),
    ("process_s", "whole process (s)", ".1f"),
)

__all__ = ["dataset_kind", "group_name", "parse_systems", "through_final_keyframes"]


def parse_systems(text: str) -> list[str]:
    """The ``--systems`` list, in the order given; an unknown name is a one-line error."""
    return orb_peer.parse_systems(text, list(SYSTEMS))


def dataset_kind(ds: Path) -> str | None:
    """``stereo`` (cam0 and cam1), ``rgbd`` (cam0 and depth0) or None (neither)."""
    mav0 = ds / "mav0"
    if not (ds / "groundtruth.tum").is_file() or not (mav0 / "cam0" / "data.csv").is_file():
        return None
    if (mav0 / "depth0" / "data.csv").is_file():
        return "rgbd"
    return "stereo" if (mav0 / "cam1" / "data.csv").is_file() else None


def group_name(name: str) -> str:
    """A dataset's name without its seed (``v102_s3`` -> ``v102``): the group its median is in."""
    return re.sub(r"_s\d+$", "", name)


def through_final_keyframes(est: Trajectory, tracked: Trajectory, final: Trajectory) -> Trajectory:
    """Each pose of ``est`` carried by the newest keyframe of ``final`` not after it (the first
    keyframe for a pose before every keyframe) from where that keyframe was when tracked
    (``tracked``'s pose at its time) to where ``final`` has it: ``T_final(k) T_tracked(k)^-1
    T_est(t)``, as ORB-SLAM3 saves a frame through its reference keyframe. A keyframe that
    ``tracked`` lacks is not used."""
    row = {int(t): i for i, t in enumerate(tracked.t_ns)}
    use = np.array([int(t) in row for t in final.t_ns], bool)
    if not use.any() or len(est) == 0:
        raise ValueError("no keyframe of the final map is among the tracked poses")
    kt = final.t_ns[use]
    Tf = final.matrices()[use]
    Tt = tracked.matrices()[[row[int(t)] for t in kt]]
    k = np.clip(np.searchsorted(kt, est.t_ns, side="right") - 1, 0, len(kt) - 1)
    carry = Tf @ np.linalg.inv(Tt)
    return Trajectory.from_matrices(est.t_ns, carry[k] @ est.matrices(), name="final")


def _events(run: Path) -> list[dict[str, object]]:
    path = run / "events.jsonl"
    lines = path.read_text(encoding="utf-8").splitlines() if path.is_file() else []
    return [json.loads(line) for line in lines if line.strip()]


def _final(gt: Path, run: Path) -> dict[str, Metric]:
    """Our final map's trajectories scored: every frame through its keyframe, the keyframes."""
    kf_path = run / "keyframes_final.tum"
    if not kf_path.is_file():
        why = na("no keyframes_final.tum (a quadnav before it was written)")
        return {"final_ape_se3_m": why, "final_coverage_pct": why, "kf_ape_se3_m": why}
    try:
        kfs = read_tum(kf_path)
        if (run / "estimate_final.tum").is_file():  # (each frame's own reference keyframe)
            final = read_tum(run / "estimate_final.tum")
        else:
            est = read_tum(run / "estimate.tum")
            final = through_final_keyframes(est, est, kfs)
    except (QuadnavError, ValueError) as exc:
        why = na(f"final trajectory: {exc}")
        return {"final_ape_se3_m": why, "final_coverage_pct": why, "kf_ape_se3_m": why}
    s, k = score(gt, final, ("se3",)), score(gt, kfs, ("se3",))
    return {"final_ape_se3_m": s["se3"], "final_matched": s["matched"], "kf_ape_se3_m": k["se3"],
            "keyframes": float(len(kfs))}  # fmt: skip


def run_quadnav(
    dataset: Path, work: Path, timeout_s: float, *, loop: bool = True
) -> dict[str, Metric]:
    """One ``quadnav slam`` process (the rig, stereo or RGB-D, read from the folder; ``loop``:
    its loop closing on, else ``--no-loop``); its causal and final trajectories scored."""
    out = work / "runs"
    cmd = [sys.executable, "-m", "quadnav", "slam", str(dataset), "--out", str(out)]
    cmd += [] if loop else ["--no-loop"]
    code, wall = _run(cmd, work / "log.txt", timeout_s)
    folders = sorted(p for p in out.glob("*") if p.is_dir()) if out.is_dir() else []
    if code != 0 or not folders or read_run_status(folders[-1]) != "complete":
        why = na(f"quadnav slam failed ({code}): {last_line(work / 'log.txt')}")
        return {"error": why, "ape_se3_m": why, "process_s": wall}
    run, gt, n = folders[-1], dataset / "groundtruth.tum", frames(dataset)
    m = json.loads((run / "metrics.json").read_text(encoding="utf-8"))
    timing = json.loads((run / "timing.json").read_text(encoding="utf-8"))
    s = score(gt, run / "estimate.tum", ("se3", "sim3"))
    f = _final(gt, run)
    kinds = [str(e.get("kind")) for e in _events(run)]
    return {
        "ape_se3_m": s["se3"], "ape_sim3_m": s["sim3"], "sim3_scale": s["sim3_scale"],
        "coverage_pct": coverage(s["matched"], n),
        "final_coverage_pct": coverage(f.pop("final_matched", f["final_ape_se3_m"]), n), **f,
        "losses": float(m["failures"]), "relocalizations": float(m["reinitializations"]),
        "loops": float(kinds.count("loop")),
        "track_ms": 1e3 * float(timing["estimator_s"]) / max(int(timing["frames"]), 1),
        "process_s": wall,
    }  # fmt: skip


def run_orb(
    dataset: Path, kind: str, peer: OrbPeer, settings: Path, work: Path, timeout_s: float,
    *, paced: bool, loop: bool = True,
) -> dict[str, Metric]:  # fmt: skip
    """One ORB-SLAM3 process in the peer's venv: ``run_orb.py stereo`` (``settings`` made by
    :func:`orb_settings`) or our ``orb_rgbd.py`` (``--no-loop`` unless ``loop``)."""
    out = work / "out"
    if kind == "stereo":
        cmd = peer.command(dataset, "stereo", settings, out, paced=paced)
    else:
        cmd = [str(peer.python), str(HERE / "orb_rgbd.py"), str(dataset), str(peer.vocab),
               str(out)] + ([] if paced else ["--no-pace"]) + ([] if loop else ["--no-loop"])  # fmt: skip
    code, wall = _run(cmd, work / "log.txt", timeout_s)
    return orb_metrics(dataset, work, code, wall)


def orb_settings(peer: OrbPeer, dataset: Path, settings: Path, *, loop: bool = True) -> None:
    """ORB-SLAM3's stereo settings for the dataset (``make_settings.py``), its loop closing
    turned off (``loopClosing: 0``) unless ``loop``."""
    peer.make_settings(dataset, settings)
    if not loop:
        with (settings / "stereo.yaml").open("a", encoding="utf-8") as f:
            f.write("loopClosing: 0\n")


def orb_metrics(dataset: Path, work: Path, code: int | str, wall: float) -> dict[str, Metric]:
    """The metrics of an ORB-SLAM3 run whose output is in ``work`` (``log.txt``, ``out/``)."""
    log = (work / "log.txt").read_text(encoding="utf-8", errors="replace")
    counts = log_counts(log)
    out, gt, n = work / "out", dataset / "groundtruth.tum", frames(dataset)
    if not (out / "stats.json").is_file():
        why = na(orb_failure(code, log, int(counts["resets"])))
        return {"error": why, "ape_se3_m": why, **counts, "process_s": wall}
    st = json.loads((out / "stats.json").read_text(encoding="utf-8"))
    online = score(gt, out / "orb_online.tum", ("se3", "sim3"))
    saved = score(gt, out / "orb_saved.tum", ("se3",))
    kf_path = out / "orb_kf_euroc.txt"
    try:
        kfs = read_orb_euroc(kf_path, camera_T_C_B(dataset))
        kf: dict[str, Metric] = {**score(gt, kfs, ("se3",)), "n": float(len(kfs))}
    except (OSError, ValueError, QuadnavError) as exc:
        kf = {"se3": na(f"{kf_path.name}: {exc}"), "n": na(f"{kf_path.name}: {exc}")}
    return {
        "ape_se3_m": online["se3"], "ape_sim3_m": online["sim3"],
        "sim3_scale": online["sim3_scale"], "coverage_pct": coverage(online["matched"], n),
        "final_ape_se3_m": saved["se3"], "final_coverage_pct": coverage(saved["matched"], n),
        "kf_ape_se3_m": kf["se3"], "keyframes": kf["n"],
        "losses": float(st["lost_events"]), **counts,
        "track_ms": float(st["track_ms_mean"]), "process_s": wall,
    }  # fmt: skip


def _arguments() -> argparse.Namespace:
    parser = peer_parser("quadnav SLAM vs ORB-SLAM3, same datasets", list(SYSTEMS),
                         "benchmarks/results/slam_peer.json")  # fmt: skip
    parser.add_argument("--quadnav-repeats", type=int, default=None, help="default --repeats")
    parser.add_argument("--no-loop", action="store_true", help="both without loop closing")
    args = parser.parse_args()
    check_arguments(args, list(SYSTEMS))
    args.quadnav_repeats = args.repeats if args.quadnav_repeats is None else args.quadnav_repeats
    if args.quadnav_repeats < 1:
        fail(f"--quadnav-repeats must be at least 1, got {args.quadnav_repeats}")
    for ds in args.datasets:
        if dataset_kind(ds) is None:
            fail(f"DATASET {ds}: no groundtruth.tum with cam0 and cam1 or depth0 (make it with "
                 "quadnav dataset make ... --rig euroc or --rig rgbd)")  # fmt: skip
    return args


def _run_dataset(
    ds: Path, systems: Sequence[str], args: argparse.Namespace, peer: OrbPeer, work: Path
) -> dict[str, object]:
    kind = dataset_kind(ds)
    mine = [s for s in systems if SYSTEMS[s][2] == kind]
    settings = work / "orb_settings"
    if kind == "stereo" and any(SYSTEMS[s][1] == "orb" for s in mine):
        orb_settings(peer, ds, settings, loop=not args.no_loop)
    record: dict[str, object] = {"dataset": dataset_record(ds), "kind": kind, "systems": {}}
    for name in mine:
        _, who, _, paced = SYSTEMS[name]

        def run_one(run_dir: Path, who: str = who, paced: bool = paced) -> dict[str, Metric]:
            if who == "quadnav":
                return run_quadnav(ds, run_dir, args.timeout, loop=not args.no_loop)
            return run_orb(ds, str(kind), peer, settings, run_dir, args.timeout, paced=paced,
                           loop=not args.no_loop)  # fmt: skip

        repeats = args.quadnav_repeats if who == "quadnav" else args.repeats
        record["systems"][name] = repeated(ds, name, repeats, work, run_one)  # type: ignore[index]
    return record


def _tables(results: Sequence[Mapping[str, object]], systems: Sequence[str]) -> str:
    """Per dataset, then the median over each group's datasets (its seeds), per system."""
    rows, groups = [], {}  # type: ignore[var-annotated]
    for res in results:
        name = Path(res["dataset"]["path"]).name  # type: ignore[index]
        for s in systems:
            med = res["systems"].get(s)  # type: ignore[attr-defined]
            if med is not None:
                rows.append((name, SYSTEMS[s][0], med["median"]))
                groups.setdefault((group_name(name), s), []).append(med["median"])
    over = []
    for (group, s), meds in groups.items():
        keys = dict.fromkeys(k for m in meds for k in m if k not in ("runs_ok", "error"))
        row = {k: median_or_na(m.get(k, na("not measured")) for m in meds) for k in keys}
        row["runs_ok"] = f"{len(meds)} seeds"
        over.append((f"{group} (median)", SYSTEMS[s][0], row))
    text = ""
    for title, columns in (("Accuracy", ACCURACY_COLUMNS), ("Counts and time", COUNT_COLUMNS)):
        text += f"{title}, per dataset (median of its runs):\n\n"
        text += markdown_table(rows, columns) + "\n\n"
        text += f"{title}, median over each motion's seeds:\n\n"
        text += markdown_table(over, columns) + "\n\n"
    return text.rstrip() + "\n"


def main() -> None:
    args = _arguments()
    peer = OrbPeer(args.orb_venv.resolve(), args.orb_dir.resolve())
    is_orb = {s: SYSTEMS[s][1] == "orb" for s in SYSTEMS}
    systems = available(args.systems, is_orb, peer, args.orb_dir)

    def run_dataset(ds: Path, work: Path) -> dict[str, object]:
        print(f"{ds}: {', '.join(systems)}", flush=True)
        return _run_dataset(ds, systems, args, peer, work)

    results = each_dataset(args.datasets, args.keep, "slam_peer_", run_dataset)
    text = _tables(results, systems)
    print(f"\n{text}")
    write_results(args.out, {
        "benchmark": "slam_peer",
        "pyorbslam3": peer.version() if any(is_orb[s] for s in systems) else None,
        "repeats": args.repeats, "quadnav_repeats": args.quadnav_repeats,
        "loop_closing": not args.no_loop,
        "systems": {s: SYSTEMS[s][0] for s in systems},
        "causal": "quadnav estimate.tum; ORB-SLAM3 orb_online.tum",
        "final": "quadnav estimate.tum through keyframes_final.tum; ORB-SLAM3 orb_saved.tum",
    }, results, text)  # fmt: skip


if __name__ == "__main__":
    main()
