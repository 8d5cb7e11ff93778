"""The KITTI drive GTSAM's Python wheel ships in its ``Data`` folder: IMU and GPS.

Three text files, as GTSAM's ``IMUKittiExampleGPS`` reads them:

* ``KittiEquivBiasedImu.txt``: a header line, then ``Time dt accelX accelY accelZ omegaX
  omegaY omegaZ`` separated by spaces (seconds, m/s^2, rad/s) at about 100 Hz. The first row's
  ``dt`` is its own time stamp (nothing came before it), and 1.9 s pass before the second row.
  The accelerometer reads about +9.8 m/s^2 on z when level: specific force with z up, the
  OXTS unit's x forward, y left, z up, which is our body frame (FLU) as it stands.
* ``KittiEquivBiasedImu_metadata.txt``: a header line and one row of twelve numbers, the IMU's
  pose in the body (metres, radians), its noise (``AccelerometerSigma``, ``GyroscopeSigma``,
  ``IntegrationSigma``, ``AccelerometerBiasSigma``, ``GyroscopeBiasSigma``) and the average
  sample period ``AverageDeltaT``.
* ``KittiGps_converted.txt``: a header line, then ``Time,X,Y,Z``, the fixes already in a local
  frame in metres with z up, at about 1 Hz.

:func:`read_gtsam_kitti` reads all three into a :class:`GtsamKitti`. A missing file, or a line
that is not what its header says, is a one-line :class:`~quadnav.errors.IoError` naming the file
and the line.
"""

from __future__ import annotations

import importlib.util
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import IoError
from quadnav.messages import ImuSample, PositionSample
from quadnav.units import s_to_ns

__all__ = [
    "GPS_FILE",
    "IMU_FILE",
    "METADATA_FILE",
    "GtsamKitti",
    "KittiImuMetadata",
    "gtsam_data_folder",
    "read_gtsam_kitti",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

IMU_FILE = "KittiEquivBiasedImu.txt"
METADATA_FILE = "KittiEquivBiasedImu_metadata.txt"
GPS_FILE = "KittiGps_converted.txt"


@dataclass(frozen=True, slots=True, kw_only=True)
class KittiImuMetadata:
    """The metadata row, named as its header names it (SI units)."""

    body_p_imu_m: tuple[float, float, float]
    body_r_imu_rad: tuple[float, float, float]
    accel_sigma: float
    gyro_sigma: float
    integration_sigma: float
    accel_bias_sigma: float
    gyro_bias_sigma: float
    average_dt_s: float


@dataclass(frozen=True, slots=True, kw_only=True)
class GtsamKitti:
    """The drive: IMU rows (body FLU) and GPS fixes (local frame, z up), times in ns."""

    folder: Path
    imu_t_ns: IntArray
    accel_m_s2: FloatArray  # (N, 3)
    gyro_rad_s: FloatArray  # (N, 3)
    gps_t_ns: IntArray
    gps_p_m: FloatArray  # (M, 3)
    metadata: KittiImuMetadata

    def imu_samples(self) -> list[ImuSample]:
        """Every IMU row as a sample."""
        return [
            ImuSample(t_ns=int(t), gyro_rad_s=g, accel_m_s2=a)
            for t, g, a in zip(self.imu_t_ns, self.gyro_rad_s, self.accel_m_s2, strict=True)
        ]

    def gps_samples(self, sigma_m: float) -> list[PositionSample]:
        """Every fix as a position of the body in the world frame, ``sigma_m`` per axis."""
        return [
            PositionSample(t_ns=int(t), p_W_B=p, sigma_m=sigma_m, source="gps")
            for t, p in zip(self.gps_t_ns, self.gps_p_m, strict=True)
        ]


def gtsam_data_folder() -> Path:
    """The ``Data`` folder of the installed GTSAM wheel (found without importing GTSAM)."""
    spec = importlib.util.find_spec("gtsam")
    if spec is None or not spec.submodule_search_locations:
        raise IoError("GTSAM is not installed: its Data folder holds the KITTI files")
    return Path(next(iter(spec.submodule_search_locations))) / "Data"


def _rows(path: Path, n_cols: int, sep: str | None) -> FloatArray:
    """The numeric rows of a file with one header line, each of ``n_cols`` finite numbers."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise IoError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise IoError(f"{path}: cannot read: {exc}") from None
    rows: list[list[float]] = []
    for k, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        tokens = line.split(sep)
        try:
            values = [float(x) for x in tokens]
        except ValueError:
            raise IoError(f"{path}:{k}: not a number in {line.strip()[:60]!r}") from None
        if len(values) != n_cols:
            raise IoError(f"{path}:{k}: expected {n_cols} values, got {len(values)}")
        if not all(math.isfinite(v) for v in values):
            raise IoError(f"{path}:{k}: a value is not finite")
        rows.append(values)
    if not rows:
        raise IoError(f"{path}: no data rows after the header")
    return np.array(rows, dtype=np.float64)


def _times_ns(path: Path, t_s: FloatArray) -> IntArray:
    t = np.array([s_to_ns(float(x)) for x in t_s], dtype=np.int64)
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        raise IoError(f"{path}:{int(bad[0]) + 3}: time does not increase")
    return t


def _metadata(path: Path) -> KittiImuMetadata:
    m = _rows(path, 12, None)
    if len(m) != 1:
        raise IoError(f"{path}: expected one row of metadata, got {len(m)}")
    v = [float(x) for x in m[0]]
    if min(v[6:8] + v[9:12]) <= 0 or v[8] < 0:
        raise IoError(f"{path}:2: noise sigmas and the period must be > 0")
    return KittiImuMetadata(
        body_p_imu_m=(v[0], v[1], v[2]),
        body_r_imu_rad=(v[3], v[4], v[5]),
        accel_sigma=v[6],
        gyro_sigma=v[7],
        integration_sigma=v[8],
        accel_bias_sigma=v[9],
        gyro_bias_sigma=v[10],
        average_dt_s=v[11],
    )


def read_gtsam_kitti(folder: Path | None = None) -> GtsamKitti:
    """Read the three files from ``folder`` (default: the installed GTSAM's ``Data``)."""
    folder = gtsam_data_folder() if folder is None else Path(folder)
    meta = _metadata(folder / METADATA_FILE)
    imu_path, gps_path = folder / IMU_FILE, folder / GPS_FILE
    imu = _rows(imu_path, 8, " ")
    gps = _rows(gps_path, 4, ",")
    return GtsamKitti(
        folder=folder,
        imu_t_ns=_times_ns(imu_path, imu[:, 0]),
        accel_m_s2=imu[:, 2:5].copy(),
        gyro_rad_s=imu[:, 5:8].copy(),
        gps_t_ns=_times_ns(gps_path, gps[:, 0]),
        gps_p_m=gps[:, 1:4].copy(),
        metadata=meta,
    )
