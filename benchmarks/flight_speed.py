"""The navigation flight's speed, per component and whole, against another tree of quadnav.

Issue 26's hot paths: the rigid body's RK4 step, the cascaded PID, the IMU's accumulation (each
simulator step), the vision pose sensor (each sample), the output predictor's step and two
rotation conversions (each IMU sample), the EKF's prediction (each IMU sample) and its update
with a vision pose (tens a second), in microseconds a call; one seeded flight of
``indoor_vision_pose`` (``run_nav``, in process, 32.5 s of flight at 500 Hz) and one task of
``benchmarks/sweep.py`` (a 60 s flight and its metrics) in seconds; and what the user feels, ``quadnav run indoor_vision_pose --seeds 1 --jobs 1`` as a
process (start, imports, the flight, metrics, plots, report). ``--before SRC`` (a ``src/`` of
another revision, e.g. ``git archive fee6776 src | tar -x -C /tmp/before``) is measured in the
same run, a repeat of each in turn, so that both see the same machine; the table gives the
ratio before/now. Pinned to ``--core``; best and median of ``--repeats``.

    python benchmarks/flight_speed.py [--before SRC] [--repeats 3] [--core 1]
        [--out benchmarks/results/flight_speed.json]
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from one_core import fail, pin_to_core

_CORE = pin_to_core(sys.argv[1:])

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

# Run in a child interpreter with the tree's src first on the path; prints one JSON line.
_CHILD = r"""
import json, time
import numpy as np
from quadnav.control.base import Setpoint, truth_estimate
from quadnav.control.cascaded_pid import CascadedPid
from quadnav.experiments.nav import run_nav
from quadnav.experiments.scenarios import nav_builtin
from quadnav.sim.rigid_body import RigidBodyQuadrotor
from quadnav.sim.sensors import IntegratingImu, VisionPoseSensor
from quadnav.vehicle import RigidBodyParams

def per_call_us(f, n):
    f()  # a first call compiles or warms
    t = time.perf_counter()
    for _ in range(n):
        f()
    return (time.perf_counter() - t) / n * 1e6

p = RigidBodyParams()
body = RigidBodyQuadrotor(p, dt_s=0.002, p0=(0.0, 0.0, 1.0), hovering=True)
cmd = np.full(4, p.hover_omega_rad_s)
truth = body.state()
est = truth_estimate(truth)
pid = CascadedPid(p, dt_s=0.002)
ref = Setpoint(p=np.array([0.3, 0.2, 1.2]), yaw_rad=0.2)
imu = IntegratingImu(period_ns=5_000_000, gyro_sigma_rad_s=0.003, accel_sigma_m_s2=0.05)
vision = VisionPoseSensor(period_ns=1, sigma_m=0.01, yaw_sigma_rad=0.01, frame_yaw_rad=0.3)
rng = np.random.default_rng(0)
ticks = iter(range(1, 10**12, 1_000_000))  # (the vision pose is due at every call)
out = {
    "rigid body step (us)": per_call_us(lambda: body.step(cmd), 20000),
    "cascaded PID (us)": per_call_us(lambda: pid(0, est, ref), 20000),
    "IMU accumulation (us)": per_call_us(lambda: imu.accumulate(truth, 0.002, rng), 20000),
    "vision pose sample (us)": per_call_us(
        lambda: vision.sample(truth, next(ticks), rng), 5000
    ),
}
from quadnav.estimation.nav_ekf import NavKinematics
from quadnav.geometry.rotations import quat_xyzw_from_matrix, so3_log
kin = NavKinematics()
R9 = np.eye(3).ravel()
w3, f3, corr = np.array([0.1, -0.2, 0.05]), np.array([0.1, 0.2, 9.8]), np.full(3, 1e-4)
out["output predictor step (us)"] = per_call_us(
    lambda: kin.integrate(truth.p_W_B, truth.v_W_B, R9, w3, f3, 0.004, corr), 20000
)
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig
from quadnav.messages import ImuSample, PoseSample
ekf = NavEkf(NavEkfConfig(), p0=np.zeros(3), v0=np.zeros(3), q0_xyzw=np.array([0, 0, 0, 1.0]),
             P0=np.eye(15) * 1e-2)
imu_s = ImuSample(t_ns=4_000_000, gyro_rad_s=w3, accel_m_s2=f3)
out["EKF prediction (us)"] = per_call_us(lambda: ekf.predict(imu_s, 0.004), 20000)
pose_times = iter(range(10**9, 10**15, 10**6))
out["EKF update, a vision pose (us)"] = per_call_us(lambda: ekf.fuse(PoseSample(
    t_ns=next(pose_times), p_W_B=ekf.p.copy(), q_W_B_xyzw=np.array([0, 0, 0, 1.0]),
    sigma_pos_m=0.01, sigma_yaw_rad=0.01)), 5000)
Rz = np.array([[0.6, -0.8, 0.0], [0.8, 0.6, 0.0], [0.0, 0.0, 1.0]])
out["quaternion of a matrix (us)"] = per_call_us(lambda: quat_xyzw_from_matrix(Rz), 20000)
out["rotation vector of a matrix (us)"] = per_call_us(lambda: so3_log(Rz), 20000)
sc = nav_builtin("indoor_vision_pose")
t = time.perf_counter()
run_nav(sc, 0)
out["flight, in process (s)"] = time.perf_counter() - t
from quadnav.experiments.sweep_tasks import _nav_task
sc60 = nav_builtin("indoor_vision_pose", ["plan.kind=takeoff_forward", "plan.takeoff_s=3.0",
    "plan.duration_s=56.5", "plan.forward_m=2", "vision.delay_s=0.25"])
_nav_task(nav_builtin("indoor_vision_pose", ["plan.kind=takeoff_forward", "plan.duration_s=1"]), 1)
t = time.perf_counter()  # (warm, as in a sweep's worker: the metrics' imports done)
_nav_task(sc60, 1)
out["60 s sweep task (s)"] = time.perf_counter() - t
print(json.dumps(out))
"""


def _child(src: Path) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": str(src)}
    res = subprocess.run(
        [sys.executable, "-c", _CHILD], env=env, capture_output=True, text=True, check=False
    )
    if res.returncode != 0:
        fail(f"the measurement failed on {src}: {res.stderr.strip().splitlines()[-1]}")
    out: dict[str, float] = json.loads(res.stdout.strip().splitlines()[-1])
    return out


def _process(src: Path) -> float:
    env = {**os.environ, "PYTHONPATH": str(src)}
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "quadnav", "run", "indoor_vision_pose", "--seeds", "1"]
        t = time.perf_counter()
        subprocess.run(
            [*cmd, "--jobs", "1", "--out", tmp], env=env, check=True, capture_output=True
        )
        return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, help="a src/ folder of another quadnav")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--core", type=int, default=1)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/flight_speed.json")
    args = ap.parse_args()
    if args.repeats < 1:
        fail(f"--repeats {args.repeats}: at least 1")
    trees = {"now": ROOT / "src"}
    if args.before is not None:
        if not (args.before / "quadnav" / "__init__.py").is_file():
            fail(f"--before {args.before}: not a src/ folder holding quadnav")
        trees["before"] = args.before.resolve()
    runs: dict[str, list[dict[str, float]]] = {k: [] for k in trees}
    for i in range(args.repeats):
        for name, src in trees.items():
            m = _child(src)
            m["whole process (s)"] = _process(src)
            runs[name].append(m)
            print(f"  repeat {i + 1}/{args.repeats} {name}: done", file=sys.stderr)
    rows = list(runs["now"][0])
    table = {
        name: {k: {"best": min(r[k] for r in rs), "median": statistics.median(r[k] for r in rs)}
               for k in rows}
        for name, rs in runs.items()
    }  # fmt: skip
    print(f"\nflight speed, one core ({_CORE}), {args.repeats} repeats, medians (best)")
    w = max(len(k) for k in rows) + 2
    head = f"  {'':{w}s}{'now':>18s}"
    if "before" in table:
        head += f"{'before':>18s}{'before/now':>12s}"
    print(head)
    for k in rows:
        now = table["now"][k]
        cell = f"{now['median']:.2f} ({now['best']:.2f})"
        line = f"  {k:{w}s}{cell:>18s}"
        if "before" in table:
            b = table["before"][k]
            cell = f"{b['median']:.2f} ({b['best']:.2f})"
            line += f"{cell:>18s}{b['median'] / now['median']:>11.2f}x"
        print(line)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    record = {
        "machine": platform.processor() or platform.machine(),
        "core": _CORE,
        "repeats": args.repeats,
        "trees": {k: str(v) for k, v in trees.items()},
        "results": table,
        "runs": runs,
    }
    args.out.write_text(json.dumps(record, indent=1))
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
