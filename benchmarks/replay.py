"""How much faster than the flight a PX4 log replays through the navigation EKF: reading the
log (pyulog) and the replay itself, best of N, for each log in ../shared/data/px4. Goal: at
least 20x. Prints a table and writes ``benchmarks/results/replay.json``.

    python benchmarks/replay.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

from quadnav.experiments.replay import config_from_px4, replay
from quadnav.io.ulog_sensors import read_ulog_sensors

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "px4"


def main() -> None:
    parser = argparse.ArgumentParser(description="log replay speed")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/replay.json"))
    args = parser.parse_args()
    rows = []
    for log in sorted(DATA.glob("*.ulg")):
        t_read, t_replay = float("inf"), float("inf")
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            s = read_ulog_sensors(log)
            t_read = min(t_read, time.perf_counter() - t0)
            r = replay(s, config_from_px4(s.params))
            t_replay = min(t_replay, r.replay_wall_s)
        rows.append({"log": log.name, "flight_s": s.duration_s, "read_s": t_read, "replay_s": t_replay,
                     "x_replay": s.duration_s / t_replay, "x_total": s.duration_s / (t_read + t_replay)})  # fmt: skip
    print(
        f"{'log':<46} {'flight s':>9} {'read s':>7} {'replay s':>9} {'x (replay)':>11} {'x (total)':>10}"
    )
    for r in rows:
        print(
            f"{r['log']:<46} {r['flight_s']:>9.1f} {r['read_s']:>7.2f} {r['replay_s']:>9.2f} {r['x_replay']:>11.1f} {r['x_total']:>10.1f}"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {"benchmark": "replay", "python": platform.python_version(), "logs": rows}, indent=2
        )
        + "\n"
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
