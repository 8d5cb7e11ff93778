"""The main job's whole process against the code before the loop was composed (issue 13).

Times what the user feels, ``quadnav run NAME --seeds 1`` as a process, for this tree and for a
baseline revision of the repository (default: the last commit before issue 13's rework), on
the same interpreter and libraries, alternating the two, best of N. Prints a table with the
ratio new/old and writes JSON.

    python benchmarks/nav_loop.py [--baseline 8519643] [--repeats 3] [--scenarios indoor_vision_pose indoor_vision]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _extract(rev: str, dest: Path) -> Path:
    """The baseline's ``src`` tree from git (no checkout of the working tree is touched)."""
    archive = dest / "base.tar"
    with archive.open("wb") as f:
        subprocess.run(["git", "-C", str(ROOT), "archive", rev, "src"], stdout=f, check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(dest, filter="data")
    return dest / "src"


def _time_run(src: Path, scenario: str, out: Path) -> float:
    env = {**os.environ, "PYTHONPATH": str(src)}
    cmd = [
        sys.executable,
        "-m",
        "quadnav",
        "run",
        scenario,
        "--seeds",
        "1",
        "--jobs",
        "1",
        "--out",
        str(out),
    ]
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default="8519643")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--scenarios", nargs="+", default=["indoor_vision_pose", "indoor_vision"])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/nav_loop.json")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        base_src = _extract(args.baseline, Path(tmp))
        for sc in args.scenarios:
            new, old = [], []
            for _ in range(args.repeats):  # alternate, so load drifts hit both alike
                new.append(_time_run(ROOT / "src", sc, Path(tmp) / "runs"))
                old.append(_time_run(base_src, sc, Path(tmp) / "runs"))
            rows.append(
                {
                    "scenario": sc,
                    "new_s": min(new),
                    "baseline_s": min(old),
                    "ratio": min(new) / min(old),
                }
            )
    print(
        f"{'quadnav run NAME --seeds 1 (whole process)':<44} {'this tree':>10} {args.baseline:>10} {'ratio':>7}"
    )
    for r in rows:
        print(
            f"{r['scenario']:<44} {r['new_s']:>9.1f}s {r['baseline_s']:>9.1f}s {r['ratio']:>7.2f}"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps({"baseline": args.baseline, "repeats": args.repeats, "rows": rows}, indent=2)
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
