"""Place recognition (``quadnav.place``): speed with 10,000 keyframes in the database, and recall
and precision on rendered worlds that are revisited.

Speed (issue 23: query plus insert at most 5 ms with 10,000 keyframes): a pool of keyframe
descriptors from renders of the built-in hall and room (``describe_image``, about 400 corners), then
``--keyframes`` keyframes, each a random pooled view with a random 80 % of its descriptors and 3 %
of their bits flipped, added to a database; then ``--queries`` more pushed through
``LoopDetector.push`` (bag of words, query, normalised scores, islands, consistency, insert),
each timed per stage on one core. Keyframes from a few hundred views of two worlds share words
far more than a long flight's would: long posting lists, a pessimistic query.

Accuracy: two laps around a circle of radius 1.5 m, 48 keyframes a lap, the camera looking out
(the second lap half a step on, 0.3 m higher, pitched and turned 5 degrees otherwise), in the
built-in room and hall and in an aliased world (one brick texture on every surface), ``--seeds`` seeds
(world and render noise). A detection is correct when the matched keyframe's bearing is within
15 degrees of the query's, false beyond 90 degrees (the camera sees 75 degrees across: such views
share nothing), in between neither.

    python benchmarks/place.py [--keyframes 10000] [--queries 300] [--seeds 5]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.geometry.camera import PinholeCamera
from quadnav.place import LoopDetector, LoopDetectorConfig, default_vocabulary, describe_image
from quadnav.sim.render import RenderEffects, Renderer, look_at
from quadnav.sim.scene import WORLDS, WorldPlan

CAMERA = PinholeCamera(
    K=np.array([[420.0, 0.0, 320.0], [0.0, 420.0, 240.0], [0.0, 0.0, 1.0]]),
    dist=np.zeros(5),
    width=640,
    height=480,
)
PER_LAP = 48
PITCH_DEG = 0.0
RADIUS_M = 1.5
#: Exclude a third of a lap (120 degrees back: no overlap with a 75-degree view).
EXCLUDE = PER_LAP // 3
CORRECT_DEG, FALSE_DEG = 15.0, 90.0


def lap_poses(lap: int) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """(bearing rad, eye, target) of a lap's keyframes: camera looking away from the centre."""
    out = []
    for i in range(PER_LAP):
        th = 2 * np.pi * (i + 0.5 * lap) / PER_LAP
        eye = np.array([RADIUS_M * np.cos(th), RADIUS_M * np.sin(th), 1.0 + 0.3 * lap])
        yaw, pitch = th + np.radians(5.0 * lap), np.radians(PITCH_DEG + 5.0 * lap)
        d = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)])
        out.append((th, eye, eye + d))
    return out


def revisit_views(world: str, seed: int) -> tuple[NDArray[np.float64], list[NDArray[np.uint8]]]:
    """Bearings and descriptors of the two laps' keyframes in ``world`` (a built-in one or
    ``aliased``), rendered with sensor noise."""
    poses = lap_poses(0) + lap_poses(1)
    path = np.array([eye for _, eye, _ in poses])
    plan = WorldPlan(flight_min_m=(-2.0, -2.0, 0.5), flight_max_m=(2.0, 2.0, 2.0), seed=seed,
                     path_W=path)  # fmt: skip
    scene = WORLDS[world](plan)
    renderer = Renderer(scene, CAMERA)
    effects, rng = (
        RenderEffects(read_noise_sigma=2.0, shot_noise_dn=0.3),
        np.random.default_rng(seed),
    )
    desc = []
    for _, eye, target in poses:
        img = effects.apply(renderer.render(look_at(eye, target)).image, rng)
        desc.append(describe_image(img)[1])
    return np.array([th for th, _, _ in poses]), desc


@dataclass(frozen=True, slots=True, kw_only=True)
class Accuracy:
    """Detections over the two laps: correct, false, in between; lap-2 queries."""

    correct: int
    false: int
    ambiguous: int
    queries: int

    @property
    def recall(self) -> float:
        return self.correct / self.queries

    @property
    def precision(self) -> float:
        return self.correct / max(self.correct + self.false, 1)


def accuracy(bearings: NDArray[np.float64], desc: list[NDArray[np.uint8]]) -> Accuracy:
    """Pushes the keyframes through a loop detector and sorts its detections by bearing."""
    det = LoopDetector(config=LoopDetectorConfig(exclude_recent=EXCLUDE))
    counts = {"correct": 0, "false": 0, "ambiguous": 0}
    for k, d in enumerate(desc):
        found = det.push(d)
        if found.detected and found.match is not None:
            diff = np.degrees(abs(np.angle(np.exp(1j * (bearings[k] - bearings[found.match])))))
            kind = (
                "correct" if diff <= CORRECT_DEG else "false" if diff > FALSE_DEG else "ambiguous"
            )
            counts[kind] += 1
    return Accuracy(**counts, queries=PER_LAP)


def pool(views: int, rng: np.random.Generator) -> list[NDArray[np.uint8]]:
    """Descriptors of ``views`` random views in the built-in hall and room."""
    out = []
    for name in ("hall", "room"):
        plan = WorldPlan(flight_min_m=(-3.0, -3.0, 0.5), flight_max_m=(3.0, 3.0, 2.5), seed=7)
        renderer = Renderer(WORLDS[name](plan), CAMERA)
        for _ in range(views // 2):
            eye, yaw, pitch = rng.uniform([-3, -3, 0.5], [3, 3, 2.5]), rng.uniform(-np.pi, np.pi), rng.uniform(-0.5, 0.2)  # fmt: skip
            d = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)])
            out.append(describe_image(renderer.render(look_at(eye, eye + d)).image)[1])
    return out


def keyframe(views: list[NDArray[np.uint8]], rng: np.random.Generator) -> NDArray[np.uint8]:
    """A random view's descriptors: 80 % of them, 3 % of their bits flipped."""
    v = views[int(rng.integers(len(views)))]
    d = v[rng.random(len(v)) < 0.8]
    return d ^ np.packbits(rng.random((len(d), 256)) < 0.03, axis=1)


def speed(n_keyframes: int, n_queries: int, views: int, seed: int) -> dict[str, object]:
    """Per-stage times (ms) of ``n_queries`` pushes into a database of ``n_keyframes``."""
    rng = np.random.default_rng(seed)
    vocab = default_vocabulary()
    source = pool(views, rng)
    det = LoopDetector(vocab)
    t0 = time.perf_counter()
    for _ in range(n_keyframes):
        det.database.add(keyframe(source, rng))
    fill_s = time.perf_counter() - t0
    stages = np.zeros((n_queries, 4))
    for q in range(n_queries):
        d = keyframe(source, rng)
        t = [time.perf_counter()]
        bow, direct = det.database.transform(d)
        t.append(time.perf_counter())
        det.detect(len(det.database), bow)
        t.append(time.perf_counter())
        det.database.add_bow(bow, direct)
        t.append(time.perf_counter())
        stages[q, :3] = np.diff(t) * 1e3
        stages[q, 3] = (t[-1] - t[0]) * 1e3
    names = ("transform", "query", "insert", "total")
    post = det.database._postings  # the inverted index's two pools, as allocated
    n = len(det.database)
    return {
        "keyframes": n_keyframes, "queries": n_queries, "pool_views": len(source),
        "descriptors_per_keyframe": float(np.mean([len(keyframe(source, rng)) for _ in range(100)])),
        "fill_s": fill_s, "words": vocab.n_words, "depth": vocab.depth,
        "inverted_index_bytes_per_keyframe": (post.entries.nbytes + post.weights.nbytes) / n,
        "postings_per_keyframe": post.end and float(post.size.sum()) / n,
        "median_ms": dict(zip(names, np.median(stages, axis=0).tolist(), strict=True)),
        "p95_ms": dict(zip(names, np.percentile(stages, 95, axis=0).tolist(), strict=True)),
    }  # fmt: skip


def _print_speed(s: dict[str, object]) -> None:
    med, p95 = s["median_ms"], s["p95_ms"]
    assert isinstance(med, dict) and isinstance(p95, dict)
    print(f"database of {s['keyframes']} keyframes ({s['descriptors_per_keyframe']:.0f} descriptors each), {s['queries']} pushes")  # fmt: skip
    print(f"inverted index: {s['inverted_index_bytes_per_keyframe']:.0f} bytes a keyframe allocated ({s['postings_per_keyframe']:.0f} postings of 8 bytes)")  # fmt: skip
    print(f"{'stage':<10} {'median ms':>10} {'p95 ms':>10}")
    for k in med:
        print(f"{k:<10} {med[k]:>10.3f} {p95[k]:>10.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description="place recognition speed and accuracy")
    parser.add_argument("--keyframes", type=int, default=10_000)
    parser.add_argument("--queries", type=int, default=300)
    parser.add_argument("--views", type=int, default=200, help="rendered views pooled")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/place.json"))
    args = parser.parse_args()
    for option, value, least in [("--keyframes", args.keyframes, 1), ("--queries", args.queries, 1),
                                 ("--views", args.views, 2), ("--seeds", args.seeds, 0)]:  # fmt: skip
        if value < least:
            print(f"error: {option} must be at least {least}, got {value}", file=sys.stderr)
            raise SystemExit(2)
    cv2.setNumThreads(1)
    s = speed(args.keyframes, args.queries, args.views, seed=0)
    _print_speed(s)
    acc: dict[str, list[dict[str, float]]] = {}
    print(f"{'world':<8} {'seed':>4} {'correct':>8} {'false':>6} {'between':>8} {'recall':>7} {'precision':>9}")  # fmt: skip
    for world in ("room", "hall", "aliased"):
        for seed in range(args.seeds):
            a = accuracy(*revisit_views(world, seed))
            acc.setdefault(world, []).append({"seed": seed, "correct": a.correct, "false": a.false, "ambiguous": a.ambiguous, "recall": a.recall, "precision": a.precision})  # fmt: skip
            print(f"{world:<8} {seed:>4} {a.correct:>8} {a.false:>6} {a.ambiguous:>8} {a.recall:>7.2f} {a.precision:>9.2f}")  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"benchmark": "place", "python": platform.python_version(), "numpy": np.__version__,
                                    "threads": 1, "speed": s, "accuracy": acc}, indent=2) + "\n")  # fmt: skip
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
