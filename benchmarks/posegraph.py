"""Pose graph optimisation time: 1,000 keyframes of a drifting odometry round a loop (10 laps of
100, ``quadnav.posegraph.simulate``) with 10 loop edges, solved by the 4-DoF graph (GTSAM's
``Pose2`` and height factors, ``native``; our ``CustomFactor``, ``custom``), the SE(3) and the
Sim(3) graph: best and median of ``--repeats`` solves each (graph building included), the
iterations, and the position error before and after against the truth.

Then why the custom graph is not solved by GTSAM's optimiser (each ``CustomFactor`` call gets a
copy of all the values). Then the GIL: the longest pause of a Python loop in the caller while the background optimiser
solves the same 4-DoF graph (``native``: no Python callback in the solve) in its thread (``executor="thread"``) and in
its worker process (``"process"``, the default), and the caller's loop rate beside each against
alone.

    python benchmarks/posegraph.py [--repeats 5] [--out benchmarks/results/posegraph.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np

from quadnav.posegraph import BackgroundPoseGraph, PoseGraphConfig, PoseGraphProblem, solve
from quadnav.posegraph.simulate import DriftingLoop, drifting_loop, position_rmse

KEYFRAMES, PER_LAP, LOOPS = 1000, 100, 10
GRAPHS = {
    "4dof native": PoseGraphConfig(kind="4dof", four_dof_factor="native"),
    "4dof custom": PoseGraphConfig(kind="4dof", four_dof_factor="custom"),
    "se3": PoseGraphConfig(kind="se3"),
    "sim3": PoseGraphConfig(kind="sim3"),
}


def time_solves(d: DriftingLoop, config: PoseGraphConfig, repeats: int) -> dict[str, float]:
    """Best and median wall time of ``repeats`` solves (building the graph included)."""
    times, result = [], None
    for _ in range(repeats):
        problem = PoseGraphProblem.from_poses(range(KEYFRAMES), d.odometry, d.loops, config=config)
        t0 = time.perf_counter()
        result = solve(problem)
        times.append(time.perf_counter() - t0)
    assert result is not None
    return {
        "best_s": min(times), "median_s": statistics.median(times), "iterations": result.iterations,
        "rmse_before_m": position_rmse(d.odometry, d.truth), "rmse_after_m": position_rmse(result.poses, d.truth),
    }  # fmt: skip


def custom_factor_in_gtsams_optimiser() -> dict[str, float]:
    """One Gauss-Newton iteration of GTSAM's optimiser over 100 ``CustomFactor``s on one
    variable, beside ``extra`` other variables that those factors do not touch, against
    ``graph.linearize`` called from Python: the optimiser hands each callback a copy of all the
    values, so its cost grows with them (why ``solve`` drives the custom graph itself)."""
    import gtsam

    def error(_: object, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        if H is not None:
            H[0] = np.eye(2)
        return np.asarray(values.atVector(0) - 1.0)

    out = {}
    for extra in (10, 1000, 10000):
        graph, values, unit = (
            gtsam.NonlinearFactorGraph(),
            gtsam.Values(),
            gtsam.noiseModel.Unit.Create(2),
        )
        values.insert(0, np.zeros(2))
        for k in range(1, extra + 1):
            values.insert(k, np.zeros(2))
            graph.add(gtsam.PriorFactorVector(k, np.zeros(2), unit))
        for _ in range(100):
            graph.add(gtsam.CustomFactor(unit, gtsam.KeyVector([0]), error))
        t0 = time.perf_counter()
        graph.linearize(values)
        t1 = time.perf_counter()
        params = gtsam.GaussNewtonParams()
        params.setMaxIterations(1)
        gtsam.GaussNewtonOptimizer(graph, values, params).optimize()
        t2 = time.perf_counter()
        out[f"extra_{extra}_linearize_ms"], out[f"extra_{extra}_optimiser_iteration_ms"] = (
            1e3 * (t1 - t0),
            1e3 * (t2 - t1),
        )
        print(f"100 CustomFactors beside {extra:>5} other variables: linearize {1e3 * (t1 - t0):6.1f} ms, one iteration of GTSAM's optimiser {1e3 * (t2 - t1):7.1f} ms")  # fmt: skip
    return out


def _spin(until: float) -> tuple[int, float]:
    """Loop until ``until``: the iterations and the longest pause between two (s), the last
    one (which may end the loop) included."""
    n, last, worst = 0, time.perf_counter(), 0.0
    while True:
        now = time.perf_counter()
        worst, last = max(worst, now - last), now
        if now >= until:
            return n, worst
        n += 1


def caller_beside(d: DriftingLoop, executor: str) -> dict[str, float]:
    """The caller's longest pause and loop rate while the background optimiser solves."""
    config = GRAPHS["4dof native"]
    with BackgroundPoseGraph(config, executor=executor) as graph:  # type: ignore[arg-type]
        for k, p in enumerate(d.odometry):
            graph.add_pose(k, p)
        graph.wait()
        time.sleep(2.0 if executor == "process" else 0.0)  # the worker's start and imports
        t0 = time.perf_counter()
        for e in d.loops:
            graph.add_loop(e)
        n, worst = 0, 0.0
        while graph.correction().result is None:
            k, w = _spin(time.perf_counter() + 0.05)
            n, worst = n + k, max(worst, w)
        wall = time.perf_counter() - t0
        solve_s = graph.correction().result.solve_s  # type: ignore[union-attr]
    return {
        "solve_s": solve_s,
        "wall_s": wall,
        "longest_pause_ms": 1e3 * worst,
        "loops_per_s": n / wall,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description="pose graph optimisation time")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/posegraph.json"))
    args = parser.parse_args()
    if args.repeats < 1:
        print(f"error: --repeats must be at least 1, got {args.repeats}", file=sys.stderr)
        raise SystemExit(2)
    d = drifting_loop(np.random.default_rng(0), keyframes=KEYFRAMES, per_lap=PER_LAP, loops=LOOPS)
    results = {name: time_solves(d, config, args.repeats) for name, config in GRAPHS.items()}
    print(f"{KEYFRAMES} keyframes, {LOOPS} loops, best and median of {args.repeats}")
    print(
        f"{'graph':<14} {'best s':>8} {'median s':>9} {'iter':>5} {'rmse before m':>14} {'after m':>8}"
    )
    for name, r in results.items():
        print(f"{name:<14} {r['best_s']:>8.3f} {r['median_s']:>9.3f} {r['iterations']:>5.0f} {r['rmse_before_m']:>14.3f} {r['rmse_after_m']:>8.3f}")  # fmt: skip
    copies = custom_factor_in_gtsams_optimiser()
    n_alone, _ = _spin(time.perf_counter() + 1.0)
    beside = {ex: caller_beside(d, ex) for ex in ("thread", "process")}
    print(f"caller alone: {n_alone:.0f} loops/s")
    print(
        f"{'executor':<10} {'solve s':>8} {'longest pause ms':>17} {'caller loops/s':>15} {'vs alone':>9}"
    )
    for ex, r in beside.items():
        print(f"{ex:<10} {r['solve_s']:>8.3f} {r['longest_pause_ms']:>17.1f} {r['loops_per_s']:>15.0f} {r['loops_per_s'] / n_alone:>9.2f}")  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"benchmark": "posegraph", "python": platform.python_version(), "gtsam": version("gtsam"),
                                    "keyframes": KEYFRAMES, "loops": LOOPS, "repeats": args.repeats, "graphs": results,
                                    "custom_factor_in_gtsams_optimiser": copies, "caller_alone_loops_per_s": n_alone, "caller_beside": beside}, indent=2) + "\n")  # fmt: skip


if __name__ == "__main__":
    main()
