"""Are the built-in worlds as hard to track as real images? The same pure rotation, seen in a
real EuRoC frame and in each world.

A real frame of ``euroc_micro`` (EuRoC V1_01_easy, cam0, undistorted) is warped by the homography
of a camera swaying in yaw and pitch (exact for a pure rotation); the worlds are rendered from a
point inside them, looking at a wall about as far as EuRoC's, under the same rotations, at the
same size. Both get the same fresh sensor noise per frame, and the same tracker (GFTT +
pyramidal KLT, VINS-Mono's front end) runs on both. Prints a table and writes JSON.

    python examples/track_realism.py ../shared/data/euroc_micro [--frames 60] [--out track_realism.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.experiments.track_study import crop_camera, rotation_study
from quadnav.io.datasets import open_dataset
from quadnav.sim.render import Renderer, look_at
from quadnav.sim.scene import WORLDS, WorldPlan

VIEWS = {  # world -> (flight box, eye, what it looks at)
    "room": (((-2.0, -1.6, 0.9), (2.0, 1.6, 1.9)), (-1.0, 0.0, 1.4), (3.0, 0.4, 1.2)),
    "hall": (((-5.0, -3.5, 1.0), (5.0, 3.5, 3.0)), (-3.0, 0.0, 2.0), (6.0, 0.5, 1.8)),
    "yard": (((-15.0, -10.0, 2.0), (15.0, 10.0, 6.0)), (0.0, 0.0, 3.0), (20.0, 2.0, 2.0)),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("euroc", type=Path, help="an EuRoC folder (euroc_micro)")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--out", type=Path, default=Path("track_realism.json"))
    args = ap.parse_args()
    ds = open_dataset(args.euroc)
    cam = ds.rig.camera("cam0").camera
    real = ds.frames_of("cam0")[0].image()
    view = crop_camera(cam.K, 560, 360)
    table: dict[str, list[dict[str, object]]] = {}
    for world, (box, eye, target) in VIEWS.items():
        scene = WORLDS[world](WorldPlan(flight_min_m=box[0], flight_max_m=box[1], seed=0))
        renderer = Renderer(scene, view)
        T_W_C0 = look_at(np.array(eye), np.array(target))

        def rendered(R: Rotation, r: Renderer = renderer, T0=T_W_C0) -> np.ndarray:  # type: ignore[no-untyped-def]
            from quadnav.geometry.rotations import Pose

            return r.render(T0 @ Pose(R, np.zeros(3))).image

        rows = rotation_study(real, cam, rendered, view, frames=args.frames)
        table[world] = [r.to_json() for r in rows]
        for r in rows:
            a, b = r.real, r.synthetic
            print(
                f"{world:<5} {r.peak_rate_deg_s:>5.0f} deg/s  tracked frame to frame "
                f"real {a.fraction_tracked.mean:.3f} / world {b.fraction_tracked.mean:.3f}   "
                f"mean track length real {a.track_length.mean:5.1f} / world {b.track_length.mean:5.1f}   "
                f"new per frame real {a.new_per_frame.mean:4.1f} / world {b.new_per_frame.mean:4.1f}"
            )
    args.out.write_text(json.dumps(table, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
