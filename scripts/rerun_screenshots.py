"""The screenshots of docs/guide/viewing.md: three runs recorded with ``--rerun`` (the default
``quadnav run`` flight, the VIO on room_easy (60 s) with its features and map, the stereo VIO with
loop closure on room_laps, the markers on the thesis's ChArUco video), each recording opened in rerun's viewer under a virtual display
and saved as a PNG, downsized.

Needs ``quadnav[viz]``, ``xvfb-run`` (Debian's ``xvfb``), ``xdotool`` (to move the virtual
display's pointer off the viewer: at the display's centre it may hover over a 3-D view and open
a tooltip) and a Vulkan driver (Mesa's lavapipe is enough: ``WGPU_BACKEND=vulkan``). The runs go under ``--runs``; built-in sequences are made
there once.

    python scripts/rerun_screenshots.py --out docs/guide/img --runs runs/screenshots
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2

#: the thesis's rig's video and calibration (the shared data beside the project's folder)
THESIS_RIG = "../shared/data/thesis_rig"
#: name, the command's arguments after ``quadnav`` (``--out RUNS`` added)
RUNS = (
    ("flight", ["run", "--rerun"]),
    ("vio", ["vio", "room_easy", "--no-video", "--rerun"]),
    ("loop", ["vio", "room_laps", "--stereo", "--loop", "--no-video", "--rerun"]),
    (
        "markers",
        [
            "markers",
            f"{THESIS_RIG}/board12_17.mp4",
            "--params",
            f"{THESIS_RIG}/vision_params.yml",
            "--camera",
            f"{THESIS_RIG}/cal.yml",
            "--set",
            "max_frames=300",
            "--rerun",
        ],
    ),
)
#: each run's folders, by name
FOLDERS = {"flight": "*_indoor_vision", "vio": "*_vio_room_easy*", "loop": "*_vio_room_laps*",
           "markers": "*_markers"}  # fmt: skip
WINDOW = "1400x900"
#: The virtual display (pixels); the pointer goes to its bottom-right corner, off the window.
SCREEN = (3200, 2000)
#: The PNG's width after downsizing (pixels).
WIDTH = 1400


def _run(args: list[str], runs: Path) -> Path:
    """Run ``quadnav ARGS --out RUNS/NAME`` and return the folder it made."""
    out = runs / args[0]
    before = set(out.iterdir()) if out.exists() else set()
    subprocess.run([sys.executable, "-m", "quadnav", *args, "--out", str(out)], check=True)
    (made,) = [p for p in set(out.iterdir()) - before if (p / "recording.rrd").is_file()]
    return made


def _reuse(args: list[str], runs: Path, name: str) -> Path:
    """The newest folder of an earlier run of ``args``, its recording built again."""
    folders = sorted((runs / args[0]).glob(FOLDERS[name]))
    subprocess.run([sys.executable, "-m", "quadnav", "view", str(folders[-1])], check=True)
    return folders[-1]


def _screenshot(recording: Path, png: Path) -> None:
    """rerun's viewer on ``recording`` under a virtual display, saved to ``png`` and downsized;
    the display's pointer moved to its far corner once the window is up (``xdotool``), where
    it hovers over nothing (the window opens at the top left, 2800 x 1800 pixels)."""
    viewer = Path(sys.executable).parent / "rerun"
    raw = png.with_suffix(".raw.png")
    env = {**os.environ, "WGPU_BACKEND": os.environ.get("WGPU_BACKEND", "vulkan"),
           "RUST_LOG": "error"}  # (no warning toasts over the views)  # fmt: skip
    w, h = SCREEN
    viewer_args = [
        str(viewer),
        str(recording),
        "--window-size",
        WINDOW,
        "--screenshot-to",
        str(raw),
    ]
    # the viewer started, its window waited for, the pointer moved (at the display's centre
    # until then, and warped back there if moved before the window is made), the viewer awaited
    pointer = (
        '"$@" & pid=$!; i=0; while [ $i -lt 600 ] && ! xdotool search --name Rerun >/dev/null '
        f"2>&1; do sleep 0.1; i=$((i+1)); done; xdotool mousemove {w - 1} {h - 1}; wait $pid"
    )
    subprocess.run(
        ["xvfb-run", "-a", "-s", f"-screen 0 {w}x{h}x24", "sh", "-c", pointer, "sh", *viewer_args],
        check=True, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=300,
    )  # fmt: skip
    image = cv2.imread(str(raw))
    h, w = image.shape[:2]
    small = cv2.resize(image, (WIDTH, round(h * WIDTH / w)), interpolation=cv2.INTER_AREA)
    cv2.imwrite(str(png), small, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    raw.unlink()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("docs/guide/img"))
    parser.add_argument("--runs", type=Path, default=Path("runs/screenshots"))
    parser.add_argument("--only", choices=[n for n, _ in RUNS], action="append")
    parser.add_argument(
        "--reuse", action="store_true", help="the newest runs under --runs, recordings rebuilt"
    )
    args = parser.parse_args()
    for tool, package in (("xvfb-run", "xvfb"), ("xdotool", "xdotool")):
        if shutil.which(tool) is None:
            sys.exit(f"error: {tool} not found (apt-get install {package})")
    args.out.mkdir(parents=True, exist_ok=True)
    for name, command in RUNS:
        if args.only and name not in args.only:
            continue
        folder = _reuse(command, args.runs, name) if args.reuse else _run(command, args.runs)
        png = args.out / f"rerun_{name}.png"
        _screenshot(folder / "recording.rrd", png)
        print(f"{png}: {folder}")


if __name__ == "__main__":
    main()
