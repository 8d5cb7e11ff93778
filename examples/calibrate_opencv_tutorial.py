"""Calibrate a camera from OpenCV's three ChArUco tutorial views and compare the result with
the calibration OpenCV computed from them (``tutorial_camera_charuco.yml``, 0.18 px).

The views (``img_00.jpg``, ``img_02.jpg``, ``img_03.jpg`` of ../shared/data/aruco) show the
tutorial board: 5x7 squares of 4 cm, markers of 2 cm, DICT_6X6_250 (``quadnav calibrate``'s
defaults). They are calibrated as ``quadnav calibrate`` does, written as OpenCV YAML, and
compared with OpenCV's result: the intrinsics with the solver's 1-sigma, and how well each
calibration fits each view (PnP reprojection error).

    python examples/calibrate_opencv_tutorial.py [../shared/data/aruco] [--out camera.yml]

The same from the command line (several image files are several SOURCEs):

    quadnav calibrate ../shared/data/aruco/img_0[023].jpg --out camera.yml

Three views are the least a calibration takes; these three show the board at nearly one angle
and reach a third of the image, so the focal length is known to about 3 % and the command
says so (its warnings); OpenCV's own result used a fourth view that is not shipped.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2

from quadnav.experiments.calibration import calibrate_source, write_source_calibration
from quadnav.io.opencv_yaml import read_camera_yaml
from quadnav.vision.calibration import rejection_summary
from quadnav.vision.markers import CharucoSpec, CharucoTarget
from quadnav.vision.pose import solve_pnp

VIEWS = ("img_00.jpg", "img_02.jpg", "img_03.jpg")
BOARD = CharucoSpec(5, 7, 0.04, 0.02, "DICT_6X6_250")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", nargs="?", type=Path, default=Path("../shared/data/aruco"))
    ap.add_argument("--out", type=Path, default=Path("camera.yml"))
    args = ap.parse_args()
    data: Path = args.data
    result = calibrate_source([str(data / name) for name in VIEWS], BOARD)
    write_source_calibration(args.out, result)
    ref_file = data / "tutorial_camera_charuco.yml"
    cal, ref = result.calibration, read_camera_yaml(ref_file)
    fs = cv2.FileStorage(str(ref_file), cv2.FILE_STORAGE_READ)
    ref_rms = float(fs.getNode("avg_reprojection_error").real())
    fs.release()
    sd = cal.std_intrinsics
    print(f"{len(cal.per_view_rms_px)} views, {rejection_summary(cal.rejected)}")
    print(f"{'':<22}{'quadnav':>10}{'1-sigma':>10}{'OpenCV':>10}")
    print(f"{'RMS error (px)':<22}{cal.rms_px:>10.3f}{'':>10}{ref_rms:>10.3f}")
    ours = (cal.camera.fx, cal.camera.fy, cal.camera.K[0, 2], cal.camera.K[1, 2])
    theirs = (ref.fx, ref.fy, ref.K[0, 2], ref.K[1, 2])
    for name, a, b in zip(("fx", "fy", "cx", "cy"), ours, theirs, strict=True):
        print(f"{name + ' (px)':<22}{a:>10.2f}{sd[name]:>10.2f}{b:>10.2f}")
    target = CharucoTarget(BOARD)
    for name in VIEWS:
        det = target.detect(cv2.imread(str(data / name)))
        points = target.chessboard_corners[det.corner_ids]
        fit = [solve_pnp(points, det.corners, cam).rms_px for cam in (cal.camera, ref)]
        print(f"{name + ' PnP (px)':<22}{fit[0]:>10.3f}{'':>10}{fit[1]:>10.3f}")
    for text in cal.warnings:
        print(f"warning: {text}")
    print(args.out)


if __name__ == "__main__":
    main()
