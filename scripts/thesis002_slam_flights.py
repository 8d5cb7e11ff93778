"""Thesis 002's six flights (hover, 1 m sigmoid, 1.2 m square; PD with Table 5.1's gains and
nested saturations) on the true state, on the true position through the serial link, and on
the stereo SLAM's position through it, over seeds: a run folder per flight (``quadnav sim``'s)
and a summary (``summary.json`` and a Markdown table on stdout).

The true-state and serial-truth flights have no randomness (no line noise by default): they
are flown once. A SLAM flight's seed draws its world (the room's layout and textures) and the
images' read noise.

    python scripts/thesis002_slam_flights.py --seeds 0-4 --out runs/slam_flights
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from quadnav.experiments.flight import BUILTIN, FlightConfig, builtin_config, run_flight
from quadnav.experiments.flight_study import write_flight_run
from quadnav.io.config import load_config

FLIGHTS = [n for n in BUILTIN if n.startswith("thesis002_slam_")]


def _seeds(text: str) -> list[int]:
    a, _, b = text.partition("-")
    return list(range(int(a), int(b or a) + 1))


def _fly(name: str, source: str, seed: int, out: Path, extra: list[str]) -> dict[str, object]:
    cfg = load_config(
        FlightConfig,
        None,
        [f"position_source={source}", f"seed={seed}", *extra],
        base=builtin_config(name),
    )
    t0 = time.perf_counter()
    run = run_flight(cfg)
    run_dir, m = write_flight_run(run, runs_root=out)
    assert m.tracking is not None
    err = np.linalg.norm(run.p - run.ref_p, axis=1)[run.t_s >= cfg.tracking_start_s]  # (the window)
    row: dict[str, object] = {
        "flight": name, "source": source, "seed": seed, "run": str(run_dir),
        "tracking_rmse_m": float(m.tracking.tracking_rmse_m),  # type: ignore[arg-type]
        "max_error_m": float(err.max()), "wall_s": time.perf_counter() - t0,
    }  # fmt: skip
    if run.link is not None:
        lm = run.link.metrics()
        row |= {k: lm[k] for k in ("sent_position_rmse_m", "sent_position_max_error_m")}
        row |= {k: v for k, v in run.link.counts.items() if not k.endswith("_ms")}
    print(json.dumps(row), flush=True)
    return row


def _windowed(rows: list[dict[str, object]]) -> list[dict[str, object]]:
    """The rows with the largest error taken over the tracking window (from each run folder's
    states.csv and config.yaml), for summaries written before the script did so."""
    import csv

    import yaml

    out = []
    for r in rows:
        folder = Path(str(r["run"]))
        start = yaml.safe_load((folder / "config.yaml").read_text()).get("tracking_start_s", 0.0)
        with (folder / "states.csv").open() as f:
            st = list(csv.DictReader(f))
        t = np.array([float(x["t_ns"]) * 1e-9 for x in st])
        p = np.array([[float(x[f"{a}_m"]) for a in "xyz"] for x in st])
        ref = np.array([[float(x[f"ref_{a}_m"]) for a in "xyz"] for x in st])
        err = np.linalg.norm(p - ref, axis=1)[t >= start]
        out.append({**r, "max_error_m": float(err.max())})
    return out


def _table(rows: list[dict[str, object]]) -> str:
    lines = [
        "| flight | truth RMSE (m) | serial truth RMSE (m) | SLAM RMSE (m), mean ± sd | "
        "SLAM max err (m), worst | SLAM position sent: RMSE (m), mean; max (m), worst | "
        "held (s), total |",
        "|---|---|---|---|---|---|---|",
    ]
    for name in FLIGHTS:
        by = {s: [r for r in rows if r["flight"] == name and r["source"] == s]
              for s in ("truth", "serial_truth", "slam")}  # fmt: skip
        slam = by["slam"]
        if not slam:
            continue
        e = np.array([r["tracking_rmse_m"] for r in slam], dtype=float)
        lines.append(
            f"| {name.removeprefix('thesis002_slam_')} "
            f"| {by['truth'][0]['tracking_rmse_m']:.4f} "
            f"| {by['serial_truth'][0]['tracking_rmse_m']:.4f} "
            f"| {e.mean():.4f} ± {e.std(ddof=1) if len(e) > 1 else 0.0:.4f} "
            f"| {max(float(r['max_error_m']) for r in slam):.3f} "  # type: ignore[arg-type]
            f"| {np.mean([float(r['sent_position_rmse_m']) for r in slam]):.4f}; "  # type: ignore[arg-type]
            f"{max(float(r['sent_position_max_error_m']) for r in slam):.3f} "  # type: ignore[arg-type]
            f"| {sum(float(r['position_held_s']) for r in slam):.1f} |"  # type: ignore[arg-type]
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-4", help="SLAM seeds, e.g. 0-4")
    ap.add_argument("--out", type=Path, default=Path("runs/slam_flights"))
    ap.add_argument("--set", action="append", default=[], help="an override for every flight")
    ap.add_argument("--flights", default=",".join(FLIGHTS))
    ap.add_argument("--table", type=Path, help="only print the table of this summary.json")
    args = ap.parse_args()
    if args.table is not None:
        print(_table(_windowed(json.loads(args.table.read_text()))))
        return
    rows: list[dict[str, object]] = []
    names = args.flights.split(",")
    args.out.mkdir(parents=True, exist_ok=True)

    def fly(name: str, source: str, seed: int) -> None:
        rows.append(_fly(name, source, seed, args.out, args.set))
        (args.out / "summary.json").write_text(json.dumps(rows, indent=1))

    for name in names:
        fly(name, "truth", 0)
        fly(name, "serial_truth", 0)
    for seed in _seeds(args.seeds):  # seed by seed: a run cut short has whole seeds
        for name in names:
            fly(name, "slam", seed)
    print(_table(rows))


if __name__ == "__main__":
    main()
