"""Sweep throughput (issue 26): N seeded flights of 60 s on the pose shortcut
(``indoor_vision_pose``) through the sweep engine on the local process pool; flights per
minute and the time 1,000 flights would take.

The whole sweep is timed as a user feels it (the pool's start-up, the workers' imports, the
table, plots and report), and each task's own wall time is read back from the table. Before
the pool starts, one task is timed alone on one core (``task_alone_s``, warm, best of three):
this machine's speed moves from day to day, and that number lets two days' sweeps be set side
by side.

    python benchmarks/sweep.py [--flights 20] [--jobs 2] [--flight-s 60]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from one_core import fail  # noqa: E402

ALIGN_S = 0.5  # estimator.align_s's default: on the ground before the take-off's wait
TAKEOFF_S = 3.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--flight-s", type=float, default=60.0, help="simulated seconds a flight")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/sweep.json")
    args = ap.parse_args()
    if args.flights < 1:
        fail(f"--flights must be at least 1, got {args.flights}")
    if args.jobs < 1:
        fail(f"--jobs must be at least 1, got {args.jobs}")
    if not ALIGN_S + TAKEOFF_S < args.flight_s <= 3600:
        fail(f"--flight-s must be in ({ALIGN_S + TAKEOFF_S:g}, 3600], got {args.flight_s:g}")

    from quadnav.experiments.sweep import plan_sweep, run_sweep, sweep_spec
    from quadnav.experiments.sweep_engines import SweepEngine
    from quadnav.io.tables import read_parquet_columns

    overrides = ["plan.kind=takeoff_forward", f"plan.takeoff_s={TAKEOFF_S}",
                 f"plan.duration_s={args.flight_s - ALIGN_S - TAKEOFF_S}", "plan.forward_m=2"]  # fmt: skip
    spec = sweep_spec(
        None, "indoor_vision_pose", ["vision.delay_s=0.25"], str(args.flights), overrides
    )
    plan = plan_sweep(spec)
    alone_s = _one_task_alone(plan)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        res = run_sweep(plan, Path(tmp) / "sweep", SweepEngine(jobs=args.jobs))
        wall_s = time.perf_counter() - t0
        table = read_parquet_columns(Path(tmp) / "sweep" / "results.parquet")
    task_s = sorted(float(w) for w in table["wall_s"] if isinstance(w, float))
    per_min = 60.0 * res.ok / wall_s
    row = {
        "flights": args.flights,
        "ok": res.ok,
        "failed": res.failed,
        "jobs": args.jobs,
        "flight_s": args.flight_s,
        "sweep_wall_s": wall_s,
        "task_wall_median_s": task_s[len(task_s) // 2] if task_s else None,
        "task_alone_s": alone_s,
        "flights_per_minute": per_min,
        "projected_1000_flights_min": 1000.0 / per_min if per_min else None,
        "cpu_count": os.cpu_count(),
    }
    print(f"{'sweep of N flights of 60 s, indoor_vision_pose, local pool':<60} {'value':>10}")
    for k, v in row.items():
        print(f"{k:<60} {v:>10.4g}" if isinstance(v, float) else f"{k:<60} {v!s:>10}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(row, indent=2) + "\n")
    print(f"wrote {args.out}")


def _one_task_alone(plan: Any) -> float:
    """The sweep's first task run here before the pool starts, warm (a first run loads the
    kernels), the best of three: this machine's speed today, on one core with the other idle,
    to set the sweep's time beside on another day."""
    point, seed = plan.task(0)
    plan.kind.run(point.config, seed)
    best = math.inf
    for _ in range(3):
        t0 = time.perf_counter()
        plan.kind.run(point.config, seed)
        best = min(best, time.perf_counter() - t0)
    return best


if __name__ == "__main__":
    main()
