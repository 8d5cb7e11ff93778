"""ORB-SLAM3 RGB-D (``pyorbslam3``'s ``Sensor.RGBD``, ``track_rgbd``) on an EuRoC folder with
depth images, as ``quadnav dataset make WORLD --rig rgbd`` writes it: ``mav0/cam0/`` and
``mav0/depth0/`` (16-bit PNGs, ``depth_scale`` counts a metre, 0 where there is no reading).
The peer's own runner (``../shared/peers/orbslam3/run_orb.py``) has no RGB-D mode; this one
writes the same files, so that the same scoring reads them: ``orb_online.tum`` (each frame's
pose when it was tracked: causal), ``orb_saved.tum`` (``SaveTrajectoryEuRoC``: every frame
through its reference keyframe's final pose), ``orb_kf_euroc.txt`` (the keyframes' final poses,
the camera's) and ``stats.json``; poses are the body's (the camera's turned by cam0's ``T_BS``).

Its settings (ORB-SLAM3 v1.0 layout, written into OUT) are cam0's calibration as the dataset
states it, the depth image's scale as ``RGBD.DepthMapFactor`` (ORB-SLAM3 divides the image by
it: counts to metres, and 0 stays "no reading"), and ``Stereo.b``, the virtual baseline its
close-point threshold ``Stereo.ThDepth`` is counted in (quadnav's: 0.05 m, 40 baselines).

It runs in the peer's venv (``pyorbslam3``, OpenCV, numpy, scipy, PyYAML; no quadnav):

    ../orb-venv/bin/python benchmarks/orb_rgbd.py DATASET VOCAB OUT [--no-pace]
        [--nfeat 1200] [--thdepth 40] [--baseline 0.05] [--no-loop]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

#: the Viewer.* keys this build of ORB-SLAM3 reads even without a viewer (as make_settings.py)
VIEWER = {
    "KeyFrameSize": 0.05, "KeyFrameLineWidth": 1.0, "GraphLineWidth": 0.9, "PointSize": 2.0,
    "CameraSize": 0.08, "CameraLineWidth": 3.0, "ViewpointX": 0.0, "ViewpointY": -0.7,
    "ViewpointZ": -1.8, "ViewpointF": 500.0, "imageViewScale": 1.0,
}  # fmt: skip


def read_yaml(path: Path) -> dict[str, Any]:
    """An EuRoC ``sensor.yaml`` (its ``%YAML:1.0`` line dropped)."""
    import yaml

    text = path.read_text(encoding="utf-8").replace("%YAML:1.0", "")
    return dict(yaml.safe_load(text))


def settings_text(
    cam: dict[str, Any], depth: dict[str, Any], *, nfeat: int, thdepth: float, baseline_m: float,
    loop: bool = True,
) -> str:  # fmt: skip
    """ORB-SLAM3 v1.0 RGB-D settings from cam0's and depth0's ``sensor.yaml`` (``loop``: its
    loop closing on, as by default, or off: ``loopClosing: 0``)."""
    if cam["camera_model"] != "pinhole" or cam["distortion_model"] != "radial-tangential":
        raise ValueError(f"cam0: {cam['camera_model']}/{cam['distortion_model']} is not pinhole")
    if depth.get("camera", "cam0") != "cam0":
        raise ValueError(f"depth0 is registered to {depth.get('camera')}, not cam0")
    fx, fy, cx, cy = (float(v) for v in cam["intrinsics"])
    k1, k2, p1, p2 = (float(v) for v in list(cam["distortion_coefficients"])[:4])
    w, h = cam["resolution"]
    lines = [
        "%YAML:1.0", "---", 'File.version: "1.0"', 'Camera.type: "PinHole"',
        f"Camera1.fx: {fx!r}", f"Camera1.fy: {fy!r}", f"Camera1.cx: {cx!r}", f"Camera1.cy: {cy!r}",
        f"Camera1.k1: {k1!r}", f"Camera1.k2: {k2!r}", f"Camera1.p1: {p1!r}", f"Camera1.p2: {p2!r}",
        f"Camera.width: {int(w)}", f"Camera.height: {int(h)}",
        f"Camera.fps: {round(float(cam['rate_hz']))}", "Camera.RGB: 1",
        f"Stereo.ThDepth: {float(thdepth)!r}", f"Stereo.b: {float(baseline_m)!r}",
        f"RGBD.DepthMapFactor: {float(depth['depth_scale'])!r}",
        f"ORBextractor.nFeatures: {int(nfeat)}", "ORBextractor.scaleFactor: 1.2",
        "ORBextractor.nLevels: 8", "ORBextractor.iniThFAST: 20", "ORBextractor.minThFAST: 7",
        *(f"Viewer.{k}: {v!r}" for k, v in VIEWER.items()),
        *([] if loop else ["loopClosing: 0"]),
    ]  # fmt: skip
    return "\n".join(lines) + "\n"


def depth_for_orb(raw: np.ndarray) -> np.ndarray:
    """A depth PNG as ORB-SLAM3's ``TrackRGBD`` takes it: float32 counts (it divides them by
    ``RGBD.DepthMapFactor``; 0, no reading, stays 0, which it skips)."""
    if raw.dtype != np.uint16 or raw.ndim != 2:
        raise ValueError(f"a depth image must be 16-bit grey, got {raw.dtype} {raw.shape}")
    return raw.astype(np.float32)


def orb_depth_m(raw: np.ndarray, depth_map_factor: float) -> np.ndarray:
    """The metres ORB-SLAM3 reads from a depth PNG (0: no reading), as its ``GrabImageRGBD``
    converts ``depth_for_orb``'s image (``convertTo(CV_32F, 1 / DepthMapFactor)``)."""
    return depth_for_orb(raw) * np.float32(1.0 / depth_map_factor)


def _rows(path: Path) -> list[list[str]]:
    text = path.read_text(encoding="utf-8").splitlines()
    return [r.strip().split(",") for r in text if r.strip() and not r.startswith("#")]


def _tum_line(t: float, T: np.ndarray) -> str:
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    return f"{t:.9f} " + " ".join(f"{v:.9f}" for v in (*T[:3, 3], *q))


def _track(a: argparse.Namespace, slam: Any, ds: Path, T_c_b: np.ndarray) -> dict[str, Any]:
    """Every frame tracked with its depth image; states, times and online poses."""
    import cv2

    cam = _rows(ds / "mav0/cam0/data.csv")
    depth = {r[0]: r[1] for r in _rows(ds / "mav0/depth0/data.csv")}
    t_img = np.array([int(r[0]) for r in cam]) * 1e-9
    states: list[str] = []
    ttrack: list[float] = []
    online: list[tuple[float, np.ndarray]] = []
    first_ok, missing = None, 0
    for k, (stamp, name) in enumerate(cam):
        if stamp not in depth:
            missing += 1
            continue
        img = cv2.imread(str(ds / "mav0/cam0/data" / name), cv2.IMREAD_GRAYSCALE)
        raw = cv2.imread(str(ds / "mav0/depth0/data" / depth[stamp]), cv2.IMREAD_UNCHANGED)
        d = depth_for_orb(raw)
        s = time.perf_counter()
        r = slam.track_rgbd(img, d, t_img[k])
        dt = time.perf_counter() - s
        ttrack.append(dt)
        states.append(str(r.state).split(".")[-1])
        if r.pose_valid:
            first_ok = t_img[k] - t_img[0] if first_ok is None else first_ok
            online.append((t_img[k], np.asarray(r.pose_wc, float) @ T_c_b))
        if k % 200 == 0:
            print(f"[rgbd] frame {k} state={states[-1]} track={dt * 1e3:.0f}ms", flush=True)
        if not a.no_pace and k + 1 < len(t_img) and dt < t_img[k + 1] - t_img[k]:
            time.sleep(t_img[k + 1] - t_img[k] - dt)
    return {"states": states, "ttrack": ttrack, "online": online, "first_ok": first_ok,
            "missing_depth": missing}  # fmt: skip


def _save(a: argparse.Namespace, slam: Any, out: Path, T_c_b: np.ndarray) -> int:
    """ORB-SLAM3's saved trajectories; ``orb_saved.tum`` as the body's. Its rows."""
    from scipy.spatial.transform import Rotation

    slam.save_trajectory_euroc(str(out / "orb_saved_euroc.txt"))
    slam.save_keyframe_trajectory_euroc(str(out / "orb_kf_euroc.txt"))
    sv = np.loadtxt(out / "orb_saved_euroc.txt", ndmin=2)
    with (out / "orb_saved.tum").open("w", encoding="utf-8") as f:
        for row in sv:
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = Rotation.from_quat(row[4:8]).as_matrix(), row[1:4]
            f.write(_tum_line(row[0] * 1e-9, T @ T_c_b) + "\n")
    return len(sv)


def main() -> None:
    ap = argparse.ArgumentParser(description="ORB-SLAM3 RGB-D on a quadnav rgbd dataset")
    ap.add_argument("ds", type=Path)
    ap.add_argument("vocab")
    ap.add_argument("out", type=Path)
    ap.add_argument("--no-pace", action="store_true", help="do not sleep to the camera rate")
    ap.add_argument("--nfeat", type=int, default=1200)
    ap.add_argument("--thdepth", type=float, default=40.0, help="in baselines (--baseline)")
    ap.add_argument("--baseline", type=float, default=0.05, help="virtual baseline (m)")
    ap.add_argument("--no-loop", action="store_true", help="loop closing off (loopClosing: 0)")
    a = ap.parse_args()
    import pyorbslam3 as pos

    a.out.mkdir(parents=True, exist_ok=True)
    cam = read_yaml(a.ds / "mav0/cam0/sensor.yaml")
    text = settings_text(cam, read_yaml(a.ds / "mav0/depth0/sensor.yaml"), nfeat=a.nfeat,
                         thdepth=a.thdepth, baseline_m=a.baseline, loop=not a.no_loop)  # fmt: skip
    (a.out / "rgbd.yaml").write_text(text, encoding="utf-8")
    T_c_b = np.linalg.inv(np.array(cam["T_BS"]["data"], float).reshape(4, 4))
    t0 = time.time()
    slam = pos.Slam(a.vocab, str(a.out / "rgbd.yaml"), pos.Sensor.RGBD, use_viewer=False)
    t_init = time.time() - t0
    wall0 = time.time()
    run = _track(a, slam, a.ds, T_c_b)
    wall = time.time() - wall0
    slam.shutdown()
    saved = _save(a, slam, a.out, T_c_b)
    with (a.out / "orb_online.tum").open("w", encoding="utf-8") as f:
        f.writelines(_tum_line(t, T) + "\n" for t, T in run["online"])
    st, tt = run["states"], np.array(run["ttrack"])
    lost = sum(
        1 for i in range(1, len(st)) if st[i] in ("LOST", "RECENTLY_LOST") and st[i - 1] == "OK"
    )
    stats = {
        "mode": "rgbd", "frames": len(st), "system_init_s": round(t_init, 2), "wall_s": round(wall, 1),
        "track_ms_mean": round(1e3 * float(tt.mean()), 1),
        "track_ms_median": round(1e3 * float(np.median(tt)), 1),
        "max_fps_tracking": round(1 / float(tt.mean()), 1), "states": dict(Counter(st)),
        "first_ok_s": run["first_ok"], "online_poses": len(run["online"]), "saved_poses": saved,
        "lost_events": lost, "missing_depth": run["missing_depth"],
    }  # fmt: skip
    (a.out / "stats.json").write_text(json.dumps(stats, indent=1), encoding="utf-8")
    print("[rgbd] STATS " + json.dumps(stats), flush=True)
    os._exit(0)  # (as run_orb.py: ORB-SLAM3's threads can hang the interpreter's exit)


if __name__ == "__main__":
    main()
