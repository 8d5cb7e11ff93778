"""``quadnav dataset make`` as the user runs it: seconds per minute of sequence, folder size per
minute, and reading the folder back (every image decoded, every IMU sample built).

Each case is the whole process (``python -m quadnav dataset make NAME --duration S``), best of N.
There is no peer tool to run beside it on this machine (Gazebo, AirSim and the like need a GPU
and a desktop), so the table states the cost per minute of data, with a mono and a stereo rig.

    python benchmarks/dataset.py [--duration 20] [--repeats 2]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CASES = (
    ("room_easy", "euroc"),  # stereo 752x480, 20 Hz, EuRoC's lens
    ("room_easy", "thesis003_sim"),  # mono 640x480, 20 Hz, no distortion
    ("room_difficult", "euroc"),  # motion blur: several renders per image
    ("hall_easy", "euroc"),
)


def _make(name: str, rig: str, duration_s: float, out: Path) -> float:
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "quadnav", "dataset", "make", name, "--rig", rig]
    cmd += ["--duration", str(duration_s), "--out", str(out)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def _read(out: Path) -> tuple[float, int]:
    from quadnav.io.datasets import open_dataset
    from quadnav.messages import ImageFrame

    t0 = time.perf_counter()
    n = 0
    for item in open_dataset(out).stream():
        if isinstance(item, ImageFrame):
            item.image()
            n += 1
    return time.perf_counter() - t0, n


def _size(out: Path) -> int:
    return sum(f.stat().st_size for f in out.rglob("*") if f.is_file())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/dataset.json")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, rig in CASES:
            out = Path(tmp) / f"{name}_{rig}"
            best = min(_make(name, rig, args.duration, out) for _ in range(args.repeats))
            read_s, images = _read(out)
            per_min = 60.0 / args.duration
            rows.append(
                {
                    "sequence": name,
                    "rig": rig,
                    "duration_s": args.duration,
                    "make_s": best,
                    "make_s_per_min": best * per_min,
                    "images": images,
                    "images_per_s": images / best,
                    "mb_per_min": _size(out) / 1e6 * per_min,
                    "read_s_per_min": read_s * per_min,
                }
            )
    print(
        f"{'dataset make (whole process)':<30} {'s/min':>7} {'images/s':>9} {'MB/min':>8} {'read s/min':>11}"
    )
    for r in rows:
        label = f"{r['sequence']} ({r['rig']})"
        print(
            f"{label:<30} {r['make_s_per_min']:>7.1f} {r['images_per_s']:>9.1f} "
            f"{r['mb_per_min']:>8.1f} {r['read_s_per_min']:>11.2f}"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"repeats": args.repeats, "rows": rows}, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
