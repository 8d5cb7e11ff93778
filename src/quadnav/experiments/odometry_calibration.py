"""What an odometry made of its rig's calibration: ``calibration.json`` in its run folder.

An odometry that refines its calibration online (:class:`~quadnav.odometry.OnlineCalibration`:
the VIO's ``estimate_extrinsic``, ``estimate_intrinsics`` and ``estimate_td``) ends a run with
each camera's extrinsic, intrinsics and time offset as it has them. The file gives, per camera,
the stated calibration (what the run was told), the estimate at the end with its standard
deviations (the window's marginals), and how far it moved.
A dataset made by ``quadnav dataset make`` keeps the calibration its data was made with in
``truth/``: then the stated and the estimated calibration are each compared with it, so a user
sees whether the online calibration went towards the truth (VINS-Mono writes its refined
extrinsic to a file in the same spirit; OpenVINS prints its calibration).

Differences are the estimate's (or the stated one's) minus the reference: the rotation between
the two ``T_B_C`` (degrees), the distance between their camera centres (m), the focal lengths
relative, the principal point in px and the time offset in ms.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from quadnav.errors import IoError
from quadnav.geometry.rotations import Pose
from quadnav.odometry import CameraCalibration, OnlineCalibration
from quadnav.rig import CameraSpec, Rig
from quadnav.units import NS_PER_S, ns_to_s

__all__ = [
    "CAMCHAIN_ONLINE", "as_calibration", "calibrated_rig", "calibration_report", "difference", "truth_rig",
]  # fmt: skip

TRUTH_FOLDER = "truth"
#: the calibration at the end of a run as a Kalibr camchain, for ``--calibration``
CAMCHAIN_ONLINE = "camchain_online.yaml"


def as_calibration(spec: CameraSpec) -> CameraCalibration:
    """A rig's camera as a calibration states it."""
    K = spec.camera.K
    return CameraCalibration(
        camera=spec.name, T_B_C=spec.T_B_C, fx=float(K[0, 0]), fy=float(K[1, 1]),
        cx=float(K[0, 2]), cy=float(K[1, 2]), time_offset_s=ns_to_s(spec.time_offset_ns),
    )  # fmt: skip


def calibrated_rig(stated: Rig, calibration: Sequence[CameraCalibration]) -> Rig:
    """``stated`` with each camera of ``calibration`` as the odometry had it: its extrinsic,
    pinhole intrinsics and time offset (the lens's distortion, resolution and rate as stated).
    Written as a Kalibr camchain (``camchain_online.yaml``), it is what a later run in the
    same rig takes with ``--calibration``."""
    by_name = {c.camera: c for c in calibration}
    cams = []
    for spec in stated.cameras:
        c = by_name.get(spec.name)
        if c is not None:
            K = np.array([[c.fx, 0.0, c.cx], [0.0, c.fy, c.cy], [0.0, 0.0, 1.0]])
            spec = replace(
                spec, camera=replace(spec.camera, K=K), T_B_C=c.T_B_C,
                time_offset_ns=round(c.time_offset_s * NS_PER_S),
            )  # fmt: skip
        cams.append(spec)
    return replace(stated, cameras=tuple(cams))


def _rotation_deg(a: Pose, b: Pose) -> float:
    R = a.R_A_B.as_matrix().T @ b.R_A_B.as_matrix()
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def difference(est: CameraCalibration, ref: CameraCalibration) -> dict[str, float]:
    """``est`` minus ``ref`` (see the module)."""
    return {
        "rotation_deg": _rotation_deg(est.T_B_C, ref.T_B_C),
        "translation_m": float(np.linalg.norm(est.T_B_C.p_A_B - ref.T_B_C.p_A_B)),
        "fx_rel": est.fx / ref.fx - 1.0,
        "fy_rel": est.fy / ref.fy - 1.0,
        "cx_px": est.cx - ref.cx,
        "cy_px": est.cy - ref.cy,
        "time_offset_ms": (est.time_offset_s - ref.time_offset_s) * 1e3,
    }


def _values(c: CameraCalibration) -> dict[str, object]:
    return {
        "T_B_C": [float(v) for v in c.T_B_C.matrix().ravel()],  # row-major 4x4 (Kalibr's T_BS)
        "intrinsics": [c.fx, c.fy, c.cx, c.cy],  # fu, fv, cu, cv as EuRoC's sensor.yaml
        "time_offset_s": c.time_offset_s,
    }


def _sigmas(c: CameraCalibration) -> dict[str, object]:
    """The estimate's standard deviations (None where it is not estimated): the extrinsic's
    rotation (deg) and translation (m) about and along the camera's axes, ``fx, fy, cx, cy``
    (px), the time offset (ms)."""
    td = c.sigma_time_offset_s
    return {
        "rotation_deg": None if c.sigma_rotation_deg is None else list(c.sigma_rotation_deg),
        "translation_m": None if c.sigma_translation_m is None else list(c.sigma_translation_m),
        "intrinsics": None if c.sigma_intrinsics_px is None else list(c.sigma_intrinsics_px),
        "time_offset_ms": None if td is None else td * 1e3,
    }


def truth_rig(root: Path | None) -> Rig | None:
    """The rig a ``quadnav dataset make`` folder's data was made with (its ``truth/``), or
    None: not such a folder, or its truth unreadable."""
    if root is None or not (Path(root) / TRUTH_FOLDER / "mav0").is_dir():
        return None
    from quadnav.io.datasets import open_dataset

    try:
        return open_dataset(Path(root), calibration=Path(root) / TRUTH_FOLDER).rig
    except IoError:
        return None


def calibration_report(
    odometry: object, stated: Rig, truth: Rig | None = None
) -> dict[str, object] | None:
    """``calibration.json``'s content (see the module), or None for an odometry that does not
    refine its calibration."""
    if not isinstance(odometry, OnlineCalibration) or not (now := odometry.calibration()):
        return None
    cams: list[dict[str, object]] = []
    for est in now:
        told = as_calibration(stated.camera(est.camera))
        entry: dict[str, object] = {
            "camera": est.camera,
            "stated": _values(told),
            "estimated": _values(est),
            "estimated_sigma": _sigmas(est),
            "estimated_minus_stated": difference(est, told),
        }
        if truth is not None and est.camera in truth.camera_names:
            true = as_calibration(truth.camera(est.camera))
            entry["truth"] = _values(true)
            entry["stated_minus_truth"] = difference(told, true)
            entry["estimated_minus_truth"] = difference(est, true)
        cams.append(entry)
    return {
        "cameras": cams,
        "truth": "the dataset's truth/ (what its data was made with)" if truth else None,
        "differences": "rotation between the two T_B_C (deg), camera centres apart (m), "
        "focal lengths relative, principal point (px), time offset (ms)",
    }
