"""Filter steps per second of the planar EKF with the delayed-horizon core and output predictor.

The simulation is run once to record the sample stream in arrival order; only the estimator
(``push`` of every sample: EKF prediction and fusion at the delayed horizon, output predictor
integration and correction at the current horizon) is timed. Prints a table and writes JSON.

    python benchmarks/planar.py [--repeats 5] [--out benchmarks/results/planar.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from quadnav.control import ThesisPlanarController, truth_estimate
from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig, PlanarEkf, PlanarEkfConfig
from quadnav.experiments import PlanarConfig, run_planar
from quadnav.messages import ImuSample, PositionSample
from quadnav.sim import DelayLine, ImuSensor, PlanarParams, PlanarQuadrotor, PositionSensor

DT_NS = 10_000_000


def record_stream(n_steps: int, delay_ns: int, seed: int = 0) -> list[ImuSample | PositionSample]:
    sim = PlanarQuadrotor(PlanarParams(), dt_ns=DT_NS)
    ctrl = ThesisPlanarController()
    imu = ImuSensor(accel_sigma_m_s2=0.25, gyro_sigma_rad_s=0.03)
    gps = PositionSensor(sigma_m=0.01, period_ns=300_000_000)
    line: DelayLine[PositionSample] = DelayLine(delay_ns=delay_ns)
    rng = np.random.default_rng(seed)
    stream: list[ImuSample | PositionSample] = []
    truth = sim.state.to_vehicle_state()
    for i in range(1, n_steps + 1):
        t = i * DT_NS
        cmd = ctrl(t, truth_estimate(truth), ctrl.setpoint(t))
        truth = sim.step(cmd.thrust_n, float(cmd.torque()[1])).to_vehicle_state()
        fix = gps.sample(truth, t, rng)
        if fix is not None:
            line.push(fix)
        stream.extend(s for _, s in line.pop_arrived(t))
        stream.append(imu.sample(truth, t, rng))
    return stream


def time_estimator(stream: list[ImuSample | PositionSample], delay_ns: int, repeats: int) -> float:
    """Median wall time (s) to push the whole stream through a fresh estimator."""
    times = []
    for _ in range(repeats):
        ekf = PlanarEkf(PlanarEkfConfig(), x0=np.zeros(5), P0=np.eye(5) * 1e-4)
        est = DelayedHorizonEstimator(
            ekf, HorizonConfig(imu_period_ns=DT_NS, max_delay_ns=delay_ns), t0_ns=0
        )
        t0 = time.perf_counter()
        for s in stream:
            est.push(s)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/planar.json"))
    args = parser.parse_args()

    rows = []
    for label, delay_ns in (
        ("no delay (buffer 1)", 0),
        ("GPS delay 1 s (buffer 101)", 1_000_000_000),
    ):
        stream = record_stream(args.steps, delay_ns)
        n_imu = sum(isinstance(s, ImuSample) for s in stream)
        seconds = time_estimator(stream, delay_ns, args.repeats)
        rows.append(
            {"case": label, "imu_steps": n_imu, "seconds": seconds, "steps_per_s": n_imu / seconds}
        )
    config = PlanarConfig(experiments=["handled"])
    t0 = time.perf_counter()
    run_planar(config, "handled", 0)
    whole = time.perf_counter() - t0
    rows.append(
        {
            "case": "whole experiment incl. simulation (10 s flight)",
            "imu_steps": args.steps,
            "seconds": whole,
            "steps_per_s": args.steps / whole,
        }
    )

    print(f"{'case':<50} {'IMU steps':>10} {'time (s)':>10} {'steps/s':>10}")
    for r in rows:
        print(
            f"{r['case']:<50} {r['imu_steps']:>10d} {r['seconds']:>10.3f} {r['steps_per_s']:>10.0f}"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {
                "benchmark": "planar",
                "python": platform.python_version(),
                "machine": platform.machine(),
                "repeats": args.repeats,
                "results": rows,
            },
            indent=2,
        )
        + "\n"
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
