"""quadnav's VIO side by side with ORB-SLAM3 (the field's reference) on the same EuRoC-format
datasets, in one run: quadnav's mono and stereo VIO (``quadnav vio DATASET [--stereo]
--no-video``) and ORB-SLAM3's mono-inertial and stereo-inertial modes, unpaced (``--paced``: at the camera's
rate, as its examples run, for its accuracy rather than its speed), through
``../shared/peers/orbslam3/`` (``make_settings.py``, ``run_orb.py [--no-pace]``) in its own venv,
each as a subprocess with a timeout; ``--repeats`` runs of each, median reported.

Accuracy is measured on the CAUSAL trajectory, the pose each frame got when it was processed:
quadnav's ``estimate.tum``, ORB-SLAM3's ``orb_online.tum``. ORB-SLAM3's saved trajectory
(``orb_saved.tum``) is refined afterwards by bundle adjustment and loop closing, and quadnav's
final trajectory (``estimate_final.tum``, ``quadnav vio --final-ba``: the whole run's graph
optimised at the end): neither is causal, and they are reported apart (SE(3) only: ORB-SLAM3's
is in its first keyframe's body frame, not level).
All trajectories are scored by the same code (``quadnav.eval``'s ``evaluate_pair``) against the
dataset's ``groundtruth.tum``: APE RMSE after a position + yaw (4-DoF) and an SE(3) alignment.
Also per run: the share of camera frames with a pose, the estimator's frames/s (quadnav: its
own timing, frames over the time spent in the estimator; ORB-SLAM3: one over its mean
``track_*`` call, its mapping threads running beside), the wall time of the whole process
(start-up and writing included), the time to initialise (quadnav: its first estimate;
ORB-SLAM3 inertial: its IMU initialisation, when its poses become metric and gravity-aligned),
failures (quadnav: failures; ORB-SLAM3: tracking lost) and resets (quadnav: re-initialisations;
ORB-SLAM3: active-map resets, counted in its log). Nothing is pinned to a core: ORB-SLAM3 is
multi-threaded, as its users run it; the 1-min load average before each run is recorded.

The peer is never a dependency of the package or of the tests: without its venv (``--orb-venv``,
with ``bin/python`` and the vocabulary ``orbvoc.txt``, set up as the peer's README says) one line
says so and quadnav's side runs alone.

    python benchmarks/vio_peer.py DATASET [DATASET ...] [--systems quadnav_mono,quadnav_stereo,
        orb_mono_inertial,orb_stereo_inertial] [--repeats 3] [--timeout 900]
        [--orb-venv ../orb-venv] [--orb-dir ../shared/peers/orbslam3] [--keep DIR] [--paced]
        [--out benchmarks/results/vio_peer.json]

DATASET: an EuRoC folder with ``groundtruth.tum`` and two cameras, as
``quadnav dataset make NAME --rig euroc --out DATASET`` writes.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import orb_peer
from orb_peer import (
    OrbPeer,
    available,
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
    repeated,
    score,
    summarise,
    write_results,
)
from orb_peer import count_resets as count_resets
from orb_peer import run_process as _run
from quadnav.eval.na import Metric, na
from quadnav.io.run_folder import read_run_status

#: name -> (label, kind, mode)
SYSTEMS: dict[str, tuple[str, str, str]] = {
    "quadnav_mono": ("quadnav VIO mono", "quadnav", "mono"),
    "quadnav_stereo": ("quadnav VIO stereo", "quadnav", "stereo"),
    "orb_mono_inertial": ("ORB-SLAM3 mono-inertial", "orb", "mono_inertial"),
    "orb_stereo_inertial": ("ORB-SLAM3 stereo-inertial", "orb", "stereo_inertial"),
}

#: the metrics of one run, medians taken over repeats (key, column heading, format)
CAUSAL_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("ape_4dof_m", "APE 4-DoF (m)", ".3f"),
    ("ape_se3_m", "APE SE(3) (m)", ".3f"),
    ("coverage_pct", "frames with pose (%)", ".0f"),
    ("init_s", "init (s)", ".1f"),
    ("failures", "failures", ".0f"),
    ("resets", "resets", ".0f"),
    ("estimator_fps", "estimator frames/s", ".1f"),
    ("process_s", "whole process (s)", ".1f"),
)
NOT_CAUSAL_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("saved_ape_se3_m", "saved / final APE SE(3) (m)", ".3f"),
    ("saved_coverage_pct", "frames in saved (%)", ".0f"),
    ("imuinit_ape_4dof_m", "online after IMU init APE 4-DoF (m)", ".3f"),
)

__all__ = ["count_resets", "markdown_table", "parse_systems", "run_orb", "summarise"]


def parse_systems(text: str) -> list[str]:
    """The ``--systems`` list, in the order given; an unknown name is a one-line error."""
    return orb_peer.parse_systems(text, list(SYSTEMS))


def run_quadnav(dataset: Path, mode: str, work: Path, timeout_s: float) -> dict[str, Metric]:
    """One ``quadnav vio`` process; its causal trajectory scored."""
    out = work / "runs"
    cmd = [sys.executable, "-m", "quadnav", "vio", str(dataset), "--no-video", "--final-ba"]
    cmd += ["--out", str(out)]
    code, wall = _run(cmd + (["--stereo"] if mode == "stereo" else []), work / "log.txt", timeout_s)
    folders = sorted(out.glob("*")) if out.is_dir() else []
    if code != 0 or not folders or read_run_status(folders[-1]) != "complete":
        why = na(f"quadnav vio failed ({code}): {last_line(work / 'log.txt')}")
        return {"error": why, "ape_4dof_m": why, "ape_se3_m": why, "process_s": wall}
    run = folders[-1]
    m = json.loads((run / "metrics.json").read_text(encoding="utf-8"))
    s = score(dataset / "groundtruth.tum", run / "estimate.tum", ("4dof", "se3"))
    saved = score(dataset / "groundtruth.tum", run / "estimate_final.tum", ("se3",))
    init = m.get("initialized_after_s")
    return {
        "ape_4dof_m": s["4dof"], "ape_se3_m": s["se3"],
        "coverage_pct": coverage(s["matched"], frames(dataset)),
        "init_s": float(init) if isinstance(init, int | float) else na("never initialised"),
        "failures": float(m["failures"]), "resets": float(m["reinitializations"]),
        "estimator_fps": float(m["timing"]["frames_per_s"]), "process_s": wall,
        "saved_ape_se3_m": saved["se3"],
        "saved_coverage_pct": coverage(saved["matched"], frames(dataset)),
    }  # fmt: skip


def run_orb(
    dataset: Path,
    mode: str,
    peer: OrbPeer,
    settings: Path,
    work: Path,
    timeout_s: float,
    *,
    paced: bool = False,
) -> dict[str, Metric]:
    """One ``run_orb.py`` process in the peer's venv (``--no-pace`` unless ``paced``: then it
    sleeps to the camera rate, as ORB-SLAM3's examples do); its trajectories scored."""
    cmd = peer.command(dataset, mode, settings, work / "out", paced=paced)
    code, wall = _run(cmd, work / "log.txt", timeout_s)
    return orb_metrics(dataset, mode, work, code, wall)


def orb_metrics(
    dataset: Path, mode: str, work: Path, code: int | str, wall: float
) -> dict[str, Metric]:
    """The metrics of a ``run_orb.py`` run whose output is in ``work`` (``log.txt``, ``out/``)."""
    log = (work / "log.txt").read_text(encoding="utf-8", errors="replace")
    resets = int(log_counts(log)["resets"])
    stats_path = work / "out" / "stats.json"
    if not stats_path.is_file():
        why = na(orb_failure(code, log, resets))
        return {"error": why, "ape_4dof_m": why, "ape_se3_m": why, "resets": float(resets),
                "process_s": wall}  # fmt: skip
    st = json.loads(stats_path.read_text(encoding="utf-8"))
    gt, out = dataset / "groundtruth.tum", work / "out"
    online = score(gt, out / "orb_online.tum", ("4dof", "se3"))
    saved = score(gt, out / "orb_saved.tum", ("se3",))
    imuinit = score(gt, out / "orb_online_imuinit.tum", ("4dof",))
    init = st.get("imu_init_s") if "inertial" in mode else st.get("first_ok_s")
    return {
        "ape_4dof_m": online["4dof"], "ape_se3_m": online["se3"],
        "coverage_pct": coverage(online["matched"], frames(dataset)),
        "init_s": float(init) if isinstance(init, int | float) else na("never initialised"),
        "failures": float(st["lost_events"]), "resets": float(resets),
        "estimator_fps": float(st["max_fps_tracking"]), "process_s": wall,
        "saved_ape_se3_m": saved["se3"],
        "saved_coverage_pct": coverage(saved["matched"], frames(dataset)),
        "imuinit_ape_4dof_m": imuinit["4dof"],
    }  # fmt: skip


def _arguments() -> argparse.Namespace:
    parser = peer_parser("quadnav VIO vs ORB-SLAM3, same datasets", list(SYSTEMS),
                         "benchmarks/results/vio_peer.json")  # fmt: skip
    parser.add_argument(
        "--paced",
        action="store_true",
        help="ORB-SLAM3 sleeps to the camera rate, as its examples do (its mapping threads get "
        "the time; its accuracy, not its speed)",
    )
    args = parser.parse_args()
    check_arguments(args, list(SYSTEMS))
    for ds in args.datasets:
        for need in ("groundtruth.tum", "mav0/cam0/data.csv", "mav0/cam1/data.csv"):
            if not (ds / need).is_file():
                fail(f"DATASET {ds}: no {need} (make it with quadnav dataset make ... --rig euroc)")
    return args


def _run_dataset(
    ds: Path, systems: Sequence[str], args: argparse.Namespace, peer: OrbPeer, work: Path
) -> dict[str, object]:
    settings = work / "orb_settings"
    if any(SYSTEMS[s][1] == "orb" for s in systems):
        peer.make_settings(ds, settings)
    record: dict[str, object] = {"dataset": dataset_record(ds), "systems": {}}
    for name in systems:
        _, kind, mode = SYSTEMS[name]

        def run_one(run_dir: Path, kind: str = kind, mode: str = mode) -> dict[str, Metric]:
            if kind == "quadnav":
                return run_quadnav(ds, mode, run_dir, args.timeout)
            return run_orb(ds, mode, peer, settings, run_dir, args.timeout, paced=args.paced)

        record["systems"][name] = repeated(ds, name, args.repeats, work, run_one)  # type: ignore[index]
    return record


def _tables(results: Sequence[Mapping[str, object]], systems: Sequence[str]) -> str:
    causal, refined = [], []
    for res in results:
        name = Path(res["dataset"]["path"]).name  # type: ignore[index]
        for s in systems:
            med = res["systems"][s]["median"]  # type: ignore[index]
            causal.append((name, SYSTEMS[s][0], med))
            refined.append((name, SYSTEMS[s][0], med))
    text = "Causal trajectories (quadnav estimate.tum, ORB-SLAM3 orb_online.tum), median:\n\n"
    text += markdown_table(causal, CAUSAL_COLUMNS)
    if refined:
        text += (
            "\n\nNot causal (ORB-SLAM3's saved trajectory, refined by bundle adjustment; "
            "quadnav's estimate_final.tum, the run's graph optimised at the end):\n\n"
        )
        text += markdown_table(refined, NOT_CAUSAL_COLUMNS)
    return text


def main() -> None:
    args = _arguments()
    peer = OrbPeer(args.orb_venv.resolve(), args.orb_dir.resolve())
    is_orb = {s: SYSTEMS[s][1] == "orb" for s in SYSTEMS}
    systems = available(args.systems, is_orb, peer, args.orb_dir)

    def run_dataset(ds: Path, work: Path) -> dict[str, object]:
        print(f"{ds}: {', '.join(systems)}, {args.repeats} repeats", flush=True)
        return _run_dataset(ds, systems, args, peer, work)

    results = each_dataset(args.datasets, args.keep, "vio_peer_", run_dataset)
    text = _tables(results, systems)
    print(f"\n{text}\n")
    orb = [s for s in systems if SYSTEMS[s][1] == "orb"]
    write_results(args.out, {
        "benchmark": "vio_peer", "pyorbslam3": peer.version() if orb else None,
        "repeats": args.repeats, "orb_paced": args.paced, "systems": {s: SYSTEMS[s][0] for s in systems},
        "causal": "quadnav estimate.tum; ORB-SLAM3 orb_online.tum (orb_saved.tum is BA-refined)",
    }, results, text)  # fmt: skip


if __name__ == "__main__":
    main()
