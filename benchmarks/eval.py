"""APE (SE(3)-aligned) and RPE on a 20,000-pose trajectory pair: quadnav against evo, same run.

In process: both tools read the same two TUM files, associate them, align the estimate with
Umeyama SE(3), and compute APE (translation) and RPE (translation, 1 frame and 10 m consecutive
pairs). Whole process, as a user runs them: ``quadnav eval ref est --align se3 --no-plots``
(which computes APE and RPE and writes its run folder) against ``evo_ape tum ref est -a`` and
against ``evo_rpe tum ref est -a --delta 10 --delta_unit m``, plus ``quadnav --help``. evo is
not a dependency of quadnav: give an interpreter that has it (``--evo-python``), e.g.

    python3 -m venv /work/evo-venv && /work/evo-venv/bin/pip install evo==1.38.1
    python benchmarks/eval.py --evo-python /work/evo-venv/bin/python

Prints a table and writes ``benchmarks/results/eval.json``. Times are the best of the repeats
(other work on the machine only ever adds time).
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.eval import align, ape, associate, error_stats, rpe
from quadnav.geometry import Trajectory
from quadnav.io import read_trajectory, write_tum

EVO_SCRIPT = r"""
import copy, json, statistics, sys, time
from evo.core import metrics, sync
from evo.core.units import Unit
from evo.tools import file_interface
ref_path, est_path, repeats = sys.argv[1], sys.argv[2], int(sys.argv[3])
stages = {"read": [], "compute": []}
out = {}
for _ in range(repeats):
    t0 = time.perf_counter()
    ref = file_interface.read_tum_trajectory_file(ref_path)
    est = file_interface.read_tum_trajectory_file(est_path)
    t1 = time.perf_counter()
    r, e = sync.associate_trajectories(ref, est, max_diff=0.01)
    e = copy.deepcopy(e)
    e.align(r, correct_scale=False)
    a = metrics.APE(metrics.PoseRelation.translation_part); a.process_data((r, e))
    p1 = metrics.RPE(metrics.PoseRelation.translation_part, 1, Unit.frames); p1.process_data((r, e))
    p10 = metrics.RPE(metrics.PoseRelation.translation_part, 10, Unit.meters); p10.process_data((r, e))
    t2 = time.perf_counter()
    stages["read"].append(t1 - t0); stages["compute"].append(t2 - t1)
    out = {"ape_rmse": a.get_statistic(metrics.StatisticsType.rmse),
           "rpe1_rmse": p1.get_statistic(metrics.StatisticsType.rmse),
           "rpe10m_rmse": p10.get_statistic(metrics.StatisticsType.rmse)}
import evo
out.update({k: min(v) for k, v in stages.items()}, version=evo.__version__)
print(json.dumps(out))
"""


def make_pair(n: int, folder: Path) -> tuple[Path, Path]:
    rng = np.random.default_rng(0)
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 20_000_000  # 50 Hz
    p = np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0)
    R = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.01, (n, 3)), axis=0))
    ref = Trajectory(t_ns=t, p_W_B=p, q_W_B_xyzw=R.as_quat())
    drift = Rotation.from_euler("z", 0.3)
    est = Trajectory(
        t_ns=t + rng.integers(-2_000_000, 2_000_000, n),
        p_W_B=drift.apply(p) + [3.0, -1.0, 0.5] + rng.normal(0, 0.02, (n, 3)),
        q_W_B_xyzw=(drift * R).as_quat(),
    )
    write_tum(folder / "ref.tum", ref)
    write_tum(folder / "est.tum", est)
    return folder / "ref.tum", folder / "est.tum"


def run_quadnav(ref_path: Path, est_path: Path, repeats: int) -> dict[str, float]:
    reads, computes = [], []
    out: dict[str, float] = {}
    for _ in range(repeats):
        t0 = time.perf_counter()
        ref, est = read_trajectory(ref_path), read_trajectory(est_path)
        t1 = time.perf_counter()
        r, e = associate(ref, est, t_max_diff_s=0.01)
        e_al, _ = align(r, e, "se3")
        a = error_stats(ape(r, e_al))
        p1, _ = rpe(r, e_al, delta=1, unit="frames")
        p10, _ = rpe(r, e_al, delta=10, unit="metres")
        t2 = time.perf_counter()
        reads.append(t1 - t0)
        computes.append(t2 - t1)
        out = {
            "ape_rmse": a["rmse"],
            "rpe1_rmse": error_stats(p1)["rmse"],
            "rpe10m_rmse": error_stats(p10)["rmse"],
        }
    return {**out, "read": min(reads), "compute": min(computes)}


def run_ok(cmd: list[str]) -> tuple[float, float]:
    """Wall and CPU (user + system) time of ``cmd`` as a whole process, start-up included.
    CPU time is the steadier figure on a shared machine: waiting for a core is not counted."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def whole_process(
    ref: Path, est: Path, runs: Path, evo_python: str | None, repeats: int
) -> dict[str, dict[str, float]]:
    """Best wall time of each command; the commands take turns, so a busy spell of the
    machine falls on all of them rather than on one."""
    quadnav = str(Path(sys.executable).with_name("quadnav"))
    eval_cmd = [quadnav, "eval", str(ref), str(est), "--align", "se3", "--no-plots"]
    cmds = {
        "quadnav --help": [quadnav, "--help"],
        "quadnav eval (APE + RPE 1 frame)": [*eval_cmd, "--out", str(runs)],
        "quadnav eval (APE + RPE 10 m)": [
            *eval_cmd, "--rpe-delta", "10", "--rpe-unit", "metres", "--out", str(runs)
        ],
    }  # fmt: skip
    if evo_python:
        bin_dir = Path(evo_python).parent
        cmds["evo_ape tum -a"] = [str(bin_dir / "evo_ape"), "tum", str(ref), str(est), "-a"]
        cmds["evo_rpe tum -a (10 m)"] = [
            str(bin_dir / "evo_rpe"), "tum", str(ref), str(est), "-a", "--delta", "10",
            "--delta_unit", "m",
        ]  # fmt: skip
    best = {name: {"wall_s": float("inf"), "cpu_s": float("inf")} for name in cmds}
    for _ in range(repeats):
        for name, cmd in cmds.items():
            wall, cpu = run_ok(cmd)
            best[name]["wall_s"] = min(best[name]["wall_s"], wall)
            best[name]["cpu_s"] = min(best[name]["cpu_s"], cpu)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description="quadnav vs evo: APE + RPE on 20,000 poses")
    parser.add_argument("--poses", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--evo-python", type=str, default=None, help="a Python with evo installed")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/eval.json"))
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        ref_path, est_path = make_pair(args.poses, Path(tmp))
        ours = run_quadnav(ref_path, est_path, args.repeats)
        walls = whole_process(ref_path, est_path, Path(tmp) / "runs", args.evo_python, args.repeats)
        evo: dict[str, float] | None = None
        if args.evo_python:
            proc = subprocess.run(
                [args.evo_python, "-c", EVO_SCRIPT, str(ref_path), str(est_path), str(args.repeats)],
                capture_output=True, text=True, check=False,
            )  # fmt: skip
            if proc.returncode != 0:
                raise SystemExit(f"evo run failed:\n{proc.stderr[-2000:]}")
            evo = json.loads(proc.stdout.strip().splitlines()[-1])

    print(
        f"{'tool':<10} {'read (s)':>10} {'compute (s)':>12} {'total (s)':>10} {'APE rmse':>10} {'RPE 1f':>10} {'RPE 10m':>10}"
    )
    rows = [("quadnav", ours)] + ([("evo", evo)] if evo else [])
    for name, r in rows:
        print(
            f"{name:<10} {r['read']:>10.3f} {r['compute']:>12.3f} {r['read'] + r['compute']:>10.3f} "
            f"{r['ape_rmse']:>10.5f} {r['rpe1_rmse']:>10.5f} {r['rpe10m_rmse']:>10.5f}"
        )
    print(
        f"\n{'whole process (best of ' + str(args.repeats) + ')':<36} {'wall (s)':>9} {'CPU (s)':>9}"
    )
    for name, w in walls.items():
        print(f"{name:<36} {w['wall_s']:>9.3f} {w['cpu_s']:>9.3f}")
    result: dict[str, object] = {
        "benchmark": "eval",
        "poses": args.poses,
        "repeats": args.repeats,
        "python": platform.python_version(),
        "quadnav": ours,
        "evo": evo,
        "whole_process_s": walls,
    }
    if "evo_ape tum -a" in walls:
        pairs = {
            "eval_se3_over_evo_ape": ("quadnav eval (APE + RPE 1 frame)", "evo_ape tum -a"),
            "eval_rpe10m_over_evo_rpe": ("quadnav eval (APE + RPE 10 m)", "evo_rpe tum -a (10 m)"),
        }
        ratios = {
            f"{k}_{t}": walls[a][f"{t}_s"] / walls[b][f"{t}_s"]
            for k, (a, b) in pairs.items()
            for t in ("wall", "cpu")
        }
        result["whole_process_ratio"] = ratios
        print(
            "whole process, quadnav eval / evo_ape: "
            f"wall {ratios['eval_se3_over_evo_ape_wall']:.2f}, "
            f"CPU {ratios['eval_se3_over_evo_ape_cpu']:.2f}; quadnav eval (RPE 10 m) / evo_rpe: "
            f"wall {ratios['eval_rpe10m_over_evo_rpe_wall']:.2f}, "
            f"CPU {ratios['eval_rpe10m_over_evo_rpe_cpu']:.2f}"
        )
    if evo:
        speedup_total = (evo["read"] + evo["compute"]) / (ours["read"] + ours["compute"])
        speedup_compute = evo["compute"] / ours["compute"]
        result.update(speedup_total=speedup_total, speedup_compute=speedup_compute)
        print(
            f"quadnav is {speedup_total:.1f}x faster than evo {evo.get('version')} in total, {speedup_compute:.1f}x in computation"
        )
    else:
        print("evo not measured: pass --evo-python PATH (an interpreter with evo installed)")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
