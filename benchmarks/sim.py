"""Simulated seconds per wall-clock second: the rigid body with the cascaded PID at 1 kHz,
and, in the same run, RotorPy flying the same hover and circle for the same duration.

RotorPy is not a dependency of quadnav: give an interpreter that has it, e.g.

    python3 -m venv /tmp/rotorpy && /tmp/rotorpy/bin/pip install rotorpy
    python benchmarks/sim.py --rotorpy-python /tmp/rotorpy/bin/python

RotorPy runs its own Multirotor (scipy solve_ivp per step) with its SE3 controller at
``sim_rate = 1000``, which is its documented way of running; both simulators log every step's
state internally. Prints a table and writes ``benchmarks/results/sim.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import time
from pathlib import Path

from quadnav.experiments.flight import FlightConfig, builtin_config, run_flight

ROTORPY_SCRIPT = r"""
import json, sys, time
import numpy as np
from rotorpy.environments import Environment
from rotorpy.vehicles.multirotor import Multirotor
from rotorpy.vehicles.crazyflie_params import quad_params
from rotorpy.controllers.quadrotor_control import SE3Control
from rotorpy.trajectories.hover_traj import HoverTraj
from rotorpy.trajectories.circular_traj import ThreeDCircularTraj
T = float(sys.argv[1])
out = {}
for name in ("hover", "circle"):
    if name == "hover":
        traj = HoverTraj(x0=np.array([0.0, 0.0, 1.5]))
        x0 = np.array([0.0, 0.0, 1.5])
    else:
        traj = ThreeDCircularTraj(center=np.array([0.0, 0.0, 1.5]), radius=np.array([2.0, 2.0, 0.0]), freq=np.array([1.0 / (4 * np.pi), 1.0 / (4 * np.pi), 0.0]))
        x0 = traj.update(0.0)["x"]
    state = {"x": x0, "v": np.zeros(3), "q": np.array([0, 0, 0, 1.0]), "w": np.zeros(3), "wind": np.zeros(3), "rotor_speeds": np.ones(4) * 1788.5}
    env = Environment(vehicle=Multirotor(quad_params, initial_state=state), controller=SE3Control(quad_params), trajectory=traj, sim_rate=1000)
    t0 = time.perf_counter()
    env.run(t_final=T, plot=False, animate_bool=False, verbose=False)
    out[name] = time.perf_counter() - t0
print(json.dumps(out))
"""


def ours(name: str, duration_s: float) -> float:
    data = builtin_config("circle")
    data["duration_s"] = duration_s
    if name == "hover":
        data["trajectory"] = {"kind": "hover", "position_m": (0.0, 0.0, 1.5)}
    config = FlightConfig.model_validate(data)
    t0 = time.perf_counter()
    run_flight(config)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(
        description="simulated seconds per wall second, quadnav vs RotorPy"
    )
    parser.add_argument("--duration", type=float, default=20.0, help="simulated seconds per flight")
    parser.add_argument("--rotorpy-python", type=str, default=None)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/sim.json"))
    args = parser.parse_args()
    T = args.duration
    results: dict[str, dict[str, float | None]] = {}
    rp: dict[str, float] | None = None
    if args.rotorpy_python:
        proc = subprocess.run(
            [args.rotorpy_python, "-c", ROTORPY_SCRIPT, str(T)],
            capture_output=True,
            text=True,
            check=False,
        )
        if proc.returncode != 0:
            raise SystemExit(f"RotorPy run failed:\n{proc.stderr[-2000:]}")
        rp = json.loads(proc.stdout.strip().splitlines()[-1])
    print(
        f"{'flight':<8} {'quadnav wall (s)':>17} {'sim s / wall s':>15} {'RotorPy wall (s)':>17} {'sim s / wall s':>15} {'ratio':>7}"
    )
    for name in ("hover", "circle"):
        w = ours(name, T)
        r = rp[name] if rp else None
        results[name] = {
            "quadnav_wall_s": w,
            "quadnav_sim_per_wall": T / w,
            "rotorpy_wall_s": r,
            "rotorpy_sim_per_wall": T / r if r else None,
            "speedup": (r / w) if r else None,
        }
        rs = f"{r:>17.2f} {T / r:>15.2f} {r / w:>7.2f}" if r else f"{'-':>17} {'-':>15} {'-':>7}"
        print(f"{name:<8} {w:>17.2f} {T / w:>15.2f} {rs}")
    if rp is None:
        print(
            "RotorPy not measured: pass --rotorpy-python PATH (an interpreter with rotorpy installed)"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {
                "benchmark": "sim",
                "duration_s": T,
                "rate_hz": 1000,
                "python": platform.python_version(),
                "results": results,
            },
            indent=2,
        )
        + "\n"
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
