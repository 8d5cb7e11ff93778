"""An incremental EuRoC ASL writer: ``mav0/cam*/data/<t_ns>.png`` + ``data.csv``, ``imu0/``,
``state_groundtruth_estimate0/``, a ``sensor.yaml`` per sensor and ``body.yaml``, and beside
``mav0/`` Kalibr's ``camchain.yaml`` and ``imu.yaml`` (PyYAML reads them) and OpenVINS'
``kalibr_imucam_chain.yaml`` and ``kalibr_imu_chain.yaml`` (``%YAML:1.0``, for OpenCV's reader).

Everything goes to ``<root>.partial/`` and is renamed to ``<root>`` by :meth:`EurocWriter.close`:
an exception (or a writer never closed) leaves no ``<root>/mav0`` that a reader would accept. A
file that cannot be written (a full disk) is an :class:`IoError` naming it: PNGs are encoded in
memory and written by Python, so libpng prints nothing of its own.
Numbers are written as ``repr`` of the floats, so they read back exactly. A radial-tangential
lens without coefficients is written with four zeros (what EuRoC's tools expect)."""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path
from typing import IO

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quadnav.errors import IoError
from quadnav.geometry.rotations import Pose
from quadnav.io.datasets.depth import DEPTH_FOLDER, depth_png, depth_yaml
from quadnav.io.datasets.files import PartialWriter, float_text
from quadnav.io.datasets.kalibr import IMU_KEYS, lens_fields, write_camchain, write_kalibr_imu
from quadnav.io.frames import cannot_write, write_png
from quadnav.messages import ImuSample
from quadnav.rig import CameraSpec, Rig

__all__ = ["TRUTH_FOLDER", "EurocWriter", "write_calibration"]

_GT = "state_groundtruth_estimate0"
#: Where a synthetic dataset keeps the calibration its data was made with (beside ``mav0/``).
TRUTH_FOLDER = "truth"
_IMU_HEADER = (
    "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
    "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n"
)
_GT_HEADER = (
    "#timestamp,p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z [],"
    "v_RS_R_x [m s^-1],v_RS_R_y [m s^-1],v_RS_R_z [m s^-1],b_w_RS_S_x [rad s^-1],"
    "b_w_RS_S_y [rad s^-1],b_w_RS_S_z [rad s^-1],b_a_RS_S_x [m s^-2],b_a_RS_S_y [m s^-2],"
    "b_a_RS_S_z [m s^-2]\n"
)


def _t_bs(T: Pose) -> str:
    data = ", ".join(float_text(x) for x in T.matrix().ravel())
    return f"T_BS:\n  cols: 4\n  rows: 4\n  data: [{data}]\n"


def camera_yaml(spec: CameraSpec) -> str:
    """A camera's EuRoC ``sensor.yaml`` (plus quadnav's ``time_offset_ns`` and ``exposure_s``)."""
    intr, dist, res = lens_fields(spec.camera)
    if spec.camera.model == "radtan" and spec.camera.dist.size == 0:
        dist = "[0.0, 0.0, 0.0, 0.0]"
    model = "equidistant" if spec.camera.model == "equidistant" else "radial-tangential"
    return (
        f"%YAML:1.0\nsensor_type: camera\ncomment: {spec.name}\n\n{_t_bs(spec.T_B_C)}\n"
        f"rate_hz: {float_text(spec.rate_hz)}\nresolution: {res}\ncamera_model: pinhole\n"
        f"intrinsics: {intr} #fu, fv, cu, cv\ndistortion_model: {model}\n"
        f"distortion_coefficients: {dist}\n"
        f"time_offset_ns: {int(spec.time_offset_ns)}\nexposure_s: {float_text(spec.exposure_s)}\n"
    )


def imu_yaml(rig: Rig) -> str:
    assert rig.imu is not None
    text = f"%YAML:1.0\nsensor_type: imu\ncomment: {rig.imu.name}\n\n{_t_bs(rig.imu.T_B_I)}"
    text += f"rate_hz: {float_text(rig.imu.rate_hz)}\n\n"
    for ours, theirs in IMU_KEYS.items():
        text += f"{theirs}: {float_text(getattr(rig.imu.noise, ours))}\n"
    return text


def write_calibration(root: Path, rig: Rig) -> None:
    """A rig's calibration as a dataset states it: ``root/mav0/<camera>/sensor.yaml``,
    ``root/mav0/imu0/sensor.yaml`` and ``root/mav0/body.yaml``, with Kalibr's ``camchain.yaml`` and
    ``imu.yaml`` and OpenVINS' ``kalibr_imucam_chain.yaml`` and ``kalibr_imu_chain.yaml`` beside
    ``mav0/``. ``quadnav``'s readers take such a folder as ``--calibration``."""
    mav0 = root / "mav0"
    for spec in rig.cameras:
        (mav0 / spec.name).mkdir(parents=True, exist_ok=True)
        (mav0 / spec.name / "sensor.yaml").write_text(camera_yaml(spec), encoding="utf-8")
    if rig.imu is not None:
        (mav0 / "imu0").mkdir(parents=True, exist_ok=True)
        (mav0 / "imu0" / "sensor.yaml").write_text(imu_yaml(rig), encoding="utf-8")
        write_kalibr_imu(root / "imu.yaml", rig)
        write_kalibr_imu(root / "kalibr_imu_chain.yaml", rig, openvins=True)
    (mav0 / "body.yaml").write_text(f"%YAML:1.0\ncomment: {rig.name}\n", "utf-8")
    write_camchain(root / "camchain.yaml", rig)
    write_camchain(root / "kalibr_imucam_chain.yaml", rig, openvins=True)


def _row(t_ns: int, values: ArrayLike) -> str:
    return (
        f"{int(t_ns)}," + ",".join(float_text(x) for x in np.asarray(values, float).ravel()) + "\n"
    )


class EurocWriter(PartialWriter):
    """Write a rig's sequence sample by sample (see the module docstring); a context manager
    that closes on success and removes the partial folder on an exception. ``rig`` is the
    calibration the dataset states (``mav0/``'s files); ``truth``, when given, the one the data
    was made with, written to ``truth/`` beside ``mav0/`` (:func:`write_calibration`), where no
    reader of the dataset looks unless told (``--calibration DIR/truth``)."""

    def __init__(
        self, root: Path | str, rig: Rig, *, overwrite: bool = False, truth: Rig | None = None
    ) -> None:
        self.root = Path(root)
        self.rig = rig
        self.truth = truth
        self.overwrite = overwrite
        if self.root.exists() and not overwrite:
            raise IoError(f"{self.root}: already exists (give overwrite=True to replace it)")
        self.partial = self.root.with_name(self.root.name + ".partial")
        if self.partial.exists():
            shutil.rmtree(self.partial)
        self.mav0 = self.partial / "mav0"
        self._files: dict[str, IO[str]] = {}
        self._paths: dict[str, Path] = {}
        self._last: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        self.closed = False
        try:
            for spec in rig.cameras:
                (self.mav0 / spec.name / "data").mkdir(parents=True)
                self._open(spec.name, f"{spec.name}/data.csv", "#timestamp [ns],filename\n")
            if rig.imu is not None:
                self._open("imu0", "imu0/data.csv", _IMU_HEADER)
            if rig.depth is not None:
                (self.mav0 / DEPTH_FOLDER / "data").mkdir(parents=True)
                self._open(DEPTH_FOLDER, f"{DEPTH_FOLDER}/data.csv", "#timestamp [ns],filename\n")
        except (OSError, IoError) as exc:
            self.abort()
            if isinstance(exc, IoError):
                raise
            raise IoError(f"{self.partial}: cannot be written ({exc.strerror})") from None

    def _open(self, key: str, rel: str, header: str) -> None:
        path = self.mav0 / rel
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._files[key] = path.open("w", encoding="utf-8")
        except OSError as exc:
            raise cannot_write(exc, path) from None
        self._paths[key] = path
        self.counts[key] = 0
        self._put(key, header)

    def _put(self, key: str, text: str) -> None:
        try:
            self._files[key].write(text)
        except OSError as exc:
            raise cannot_write(exc, self._paths[key]) from None

    def _stamp(self, key: str, t_ns: int) -> None:
        if self.closed:
            raise IoError(f"{self.root}: the writer is closed")
        if isinstance(t_ns, bool) or not isinstance(t_ns, int | np.integer) or t_ns < 0:
            raise IoError(f"{key}: t_ns must be a non-negative integer, got {t_ns!r}")
        last = self._last.get(key)
        if last is not None and t_ns <= last:
            raise IoError(f"{key}: t_ns {t_ns} is not after the previous {last}")
        self._last[key] = int(t_ns)
        self.counts[key] = self.counts.get(key, 0) + 1

    def add_frame(self, camera: str, t_ns: int, image: NDArray[np.uint8]) -> None:
        """One image of ``camera`` (grey or BGR uint8, the camera's resolution) as a PNG."""
        if camera not in self.rig.camera_names:
            raise IoError(f"camera {camera!r} is not one of the rig's {self.rig.camera_names}")
        lens = self.rig.camera(camera).camera
        img = np.asarray(image)
        if img.dtype != np.uint8 or img.shape[:2] != (lens.height, lens.width):
            raise IoError(
                f"{camera}: image must be uint8 {lens.height}x{lens.width}, "
                f"got {img.dtype} {img.shape}"
            )
        self._stamp(camera, t_ns)
        name = f"{int(t_ns)}.png"
        write_png(self.mav0 / camera / "data" / name, img)
        self._put(camera, f"{int(t_ns)},{name}\n")

    def add_depth(self, t_ns: int, depth_m: NDArray[np.floating]) -> None:
        """One depth image (metres, ``inf`` where nothing is read) of the rig's depth sensor,
        as a 16-bit PNG of millimetres."""
        if self.rig.depth is None:
            raise IoError(f"rig {self.rig.name!r} has no depth sensor")
        lens = self.rig.camera(self.rig.depth.camera).camera
        if np.shape(depth_m) != (lens.height, lens.width):
            raise IoError(
                f"{DEPTH_FOLDER}: depth must be {lens.height}x{lens.width}, got {np.shape(depth_m)}"
            )
        self._stamp(DEPTH_FOLDER, t_ns)
        name = f"{int(t_ns)}.png"
        write_png(self.mav0 / DEPTH_FOLDER / "data" / name, depth_png(depth_m))
        self._put(DEPTH_FOLDER, f"{int(t_ns)},{name}\n")

    def add_imu(self, sample: ImuSample) -> None:
        if self.rig.imu is None:
            raise IoError(f"rig {self.rig.name!r} has no IMU")
        self._stamp("imu0", sample.t_ns)
        self._put("imu0", _row(sample.t_ns, np.r_[sample.gyro_rad_s, sample.accel_m_s2]))

    def add_groundtruth(
        self,
        t_ns: int,
        p: ArrayLike,
        q: ArrayLike,
        v: ArrayLike = (0.0, 0.0, 0.0),
        bg: ArrayLike = (0.0, 0.0, 0.0),
        ba: ArrayLike = (0.0, 0.0, 0.0),
    ) -> None:
        """The body's pose (``q`` x, y, z, w; written w first as EuRoC), velocity, biases."""
        values = [np.asarray(a, dtype=np.float64).ravel() for a in (p, q, v, bg, ba)]
        if [a.size for a in values] != [3, 4, 3, 3, 3] or not all(
            np.isfinite(a).all() for a in values
        ):
            raise IoError(f"ground truth at {t_ns}: p, v, bg, ba need 3 and q 4 finite numbers")
        if _GT not in self._files:
            self._open(_GT, f"{_GT}/data.csv", _GT_HEADER)
        self._stamp(_GT, t_ns)
        p_, q_, v_, bg_, ba_ = values
        self._put(_GT, _row(t_ns, np.r_[p_, q_[[3, 0, 1, 2]], v_, bg_, ba_]))

    def _write_yaml(self) -> None:
        write_calibration(self.partial, self.rig)
        if _GT in self._files:
            text = f"%YAML:1.0\nsensor_type: visual-inertial\n{_t_bs(Pose.identity())}"
            (self.mav0 / _GT / "sensor.yaml").write_text(text, encoding="utf-8")
        if self.rig.depth is not None:
            text = depth_yaml(self.rig.depth)
            (self.mav0 / DEPTH_FOLDER / "sensor.yaml").write_text(text, encoding="utf-8")
        if self.truth is not None:
            write_calibration(self.partial / TRUTH_FOLDER, self.truth)

    def close(self) -> Path:
        """Finish the files and move the folder to ``root``; the root's path."""
        if self.closed:
            return self.root
        path = self.partial
        try:
            for key, fh in self._files.items():
                path = self._paths[key]
                fh.close()  # the last buffered rows are written here
            path = self.partial
            self._write_yaml()
            if self.root.exists():
                shutil.rmtree(self.root)
            self.partial.rename(self.root)
        except OSError as exc:
            raise cannot_write(exc, path) from None
        self.closed = True
        return self.root

    def abort(self) -> None:
        """Drop what was written (the partial folder)."""
        for fh in self._files.values():
            with contextlib.suppress(OSError):  # a full disk: the folder goes anyway
                fh.close()
        shutil.rmtree(self.partial, ignore_errors=True)
        self.closed = True
