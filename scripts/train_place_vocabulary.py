"""Trains the vocabulary tree quadnav ships (``src/quadnav/place/data/orb_vocabulary.npz``).

Training images, all different from the built-in test worlds (room, hall, yard, marker floor):
- renders of ``--worlds`` training rooms of random size, built here: an enclosure, crates and
  posters, textured with the procedural kinds at seeds 100 and up (the built-in worlds draw
  seeds 0..7) and the training photos only;
- the training photos themselves, flat, at two sizes and two albedo seeds.

Photos used for training: brick, grass, moon, text, coins, cell, camera. Held out (never seen by
training, so a test world showing them checks that the vocabulary generalises): gravel, coffee,
rocket, astronaut, page, chelsea, hubble_deep_field.

Every image is described as a keyframe is (``quadnav.place.describe_image``: Shi-Tomasi corners,
ORB's BRIEF at angle 0). Reproducible from ``--seed``: each world and its views draw from their
own child of ``SeedSequence(seed)``.

    python scripts/train_place_vocabulary.py [--seed 0] [--worlds 60] [--views 20] \
        [--branching 10] [--depth 5] [--out src/quadnav/place/data/orb_vocabulary.npz]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from quadnav.geometry.camera import PinholeCamera
from quadnav.place import describe_image, train_vocabulary
from quadnav.sim.render import Renderer, look_at
from quadnav.sim.scene import Scene, Texture, TexturedPolygon, box, polygon, tessellate
from quadnav.sim.textures import PROCEDURAL, make_texture

TRAIN_PHOTOS = ("brick", "grass", "moon", "text", "coins", "cell", "camera")
HELD_OUT_PHOTOS = (
    "gravel",
    "coffee",
    "rocket",
    "astronaut",
    "page",
    "chelsea",
    "hubble_deep_field",
)
#: Procedural textures of training worlds start at this seed (the built-in worlds use 0..7).
FIRST_SEED = 100
CAMERA = PinholeCamera(
    K=np.array([[420.0, 0.0, 320.0], [0.0, 420.0, 240.0], [0.0, 0.0, 1.0]]),
    dist=np.zeros(5),
    width=640,
    height=480,
)


def _texture(rng: np.random.Generator, m_per_texel: float) -> Texture:
    kinds = (*PROCEDURAL, *TRAIN_PHOTOS)
    kind = kinds[int(rng.integers(len(kinds)))]
    seed = FIRST_SEED + int(rng.integers(1000))
    return Texture(make_texture(kind, seed, 512), m_per_texel, f"{kind}:{seed}")


def _cells(polys: list[TexturedPolygon]) -> list[TexturedPolygon]:
    return [c for p in polys for c in tessellate(p, 2.0)]


def training_world(
    rng: np.random.Generator,
) -> tuple[Scene, NDArray[np.float64], NDArray[np.float64]]:
    """A room of random size with crates and posters; its inner box (where views are taken)."""
    size = rng.uniform([4.0, 4.0, 2.6], [14.0, 12.0, 6.0])
    lo, hi = np.zeros(3), size
    faces = box(lo, hi, [_texture(rng, rng.uniform(0.003, 0.01)) for _ in range(6)], inward=True,
                rng=rng, name="enclosure")  # fmt: skip
    polys = _cells(faces)
    for i in range(int(rng.integers(3, 10))):
        s = rng.uniform([0.3, 0.3, 0.3], [1.5, 2.0, 2.0])
        p = rng.uniform([0.2, 0.2], size[:2] - s[:2] - 0.2)
        c_lo = np.array([p[0], p[1], 0.0])
        polys += _cells(box(c_lo, c_lo + s, _texture(rng, 0.003), rng=rng, name=f"crate {i}"))
    for wall in [f for f in faces if abs(f.normal_W[2]) < 0.5]:
        if rng.random() < 0.6:
            side = rng.uniform(0.6, 2.0)
            c = wall.points_W.mean(axis=0) + 0.002 * wall.normal_W
            u, v = wall.u_W * side / 2, wall.v_W * side / 2
            name = TRAIN_PHOTOS[int(rng.integers(len(TRAIN_PHOTOS)))]
            tex = Texture(make_texture(name, FIRST_SEED, 512), side / 512, f"poster {name}")
            pts = np.array([c - u - v, c - u + v, c + u + v, c + u - v])
            polys.append(polygon(pts, tex, u_dir_W=wall.u_W, name="poster"))
    inner_lo = np.array([0.6, 0.6, 0.5])
    return Scene(tuple(polys), "training"), inner_lo, hi - np.array([0.6, 0.6, 0.5])


def world_descriptors(rng: np.random.Generator, views: int) -> list[NDArray[np.uint8]]:
    """The descriptors of ``views`` random views of one training world."""
    scene, lo, hi = training_world(rng)
    renderer = Renderer(scene, CAMERA)
    out = []
    for _ in range(views):
        eye = rng.uniform(lo, hi)
        yaw, pitch = rng.uniform(-np.pi, np.pi), rng.uniform(-0.6, 0.3)
        d = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)])
        img = renderer.render(look_at(eye, eye + d)).image
        out.append(describe_image(img)[1])
    return out


def photo_descriptors() -> list[NDArray[np.uint8]]:
    """The training photos themselves, at 512 and 1024 pixels, two albedo seeds each."""
    return [
        describe_image(make_texture(name, seed, size))[1]
        for name in TRAIN_PHOTOS
        for size in (512, 1024)
        for seed in (FIRST_SEED, FIRST_SEED + 1)
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description="train quadnav's place vocabulary")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--worlds", type=int, default=60)
    parser.add_argument("--views", type=int, default=20)
    parser.add_argument("--branching", type=int, default=10)
    parser.add_argument("--depth", type=int, default=5)
    parser.add_argument(
        "--out", type=Path, default=Path("src/quadnav/place/data/orb_vocabulary.npz")
    )
    args = parser.parse_args()
    t0 = time.perf_counter()
    seqs = np.random.SeedSequence(args.seed).spawn(args.worlds + 1)
    images = photo_descriptors()
    for k in range(args.worlds):
        images += world_descriptors(np.random.default_rng(seqs[k]), args.views)
        print(f"world {k + 1}/{args.worlds}: {sum(map(len, images))} descriptors", flush=True)
    desc = np.concatenate(images)
    image_of = np.repeat(np.arange(len(images)), [len(d) for d in images])
    t1 = time.perf_counter()
    vocab = train_vocabulary(
        desc, image_of, branching=args.branching, depth=args.depth,
        rng=np.random.default_rng(seqs[-1]),
    )  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out, **vocab.to_arrays())
    print(
        f"{len(images)} images, {len(desc)} descriptors ({t1 - t0:.0f} s); "
        f"{len(vocab.centres)} nodes, {vocab.n_words} words, depth {vocab.depth} "
        f"({time.perf_counter() - t1:.0f} s); {args.out}: {args.out.stat().st_size} bytes"
    )


if __name__ == "__main__":
    main()
