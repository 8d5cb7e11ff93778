"""Throughput of the serial frame decoder (thesis 002's X<cm>Y<cm>Z<cm>F): frames per second
decoded from a stream of valid frames, and from one with 30 % garbage bytes interleaved, fed
in 64-byte chunks as a UART driver would. At 115200 8N1 a link carries at most about 870 such
frames per second. Prints a table and writes ``benchmarks/results/serial_frame.json``.

    python benchmarks/serial_frame.py [--frames 100000]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from quadnav.io.serial_frame import FrameDecoder, encode


def run(stream: bytes, repeats: int = 3) -> tuple[float, int]:
    best, n = float("inf"), 0
    for _ in range(repeats):
        dec = FrameDecoder()
        t0 = time.perf_counter()
        for i in range(0, len(stream), 64):
            dec.feed(stream[i : i + 64])
        best = min(best, time.perf_counter() - t0)
        n = dec.frames
    return best, n


def main() -> None:
    parser = argparse.ArgumentParser(description="serial frame decoder throughput")
    parser.add_argument("--frames", type=int, default=100_000)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/serial_frame.json"))
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    pos = rng.uniform(-50, 50, (args.frames, 3))
    frames = [encode(*p) for p in pos]
    clean = b"".join(frames)
    noisy = bytearray()
    for f in frames:
        noisy += f
        g = rng.integers(0, 256, int(len(f) * 0.3), dtype=np.uint8).tobytes().replace(b"X", b"x")
        noisy += g
    rows = []
    for name, stream in (("valid frames", clean), ("30 % garbage interleaved", bytes(noisy))):
        t, n = run(stream)
        rows.append({"stream": name, "bytes": len(stream), "frames": n, "seconds": t, "frames_per_s": n / t, "mb_per_s": len(stream) / t / 1e6})  # fmt: skip
    print(f"{'stream':<28} {'frames':>8} {'frames/s':>10} {'MB/s':>6}")
    for r in rows:
        print(
            f"{r['stream']:<28} {r['frames']:>8} {r['frames_per_s']:>10.0f} {r['mb_per_s']:>6.2f}"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {"benchmark": "serial_frame", "python": platform.python_version(), "rows": rows},
            indent=2,
        )
        + "\n"
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
