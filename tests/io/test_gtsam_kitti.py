"""The reader of the KITTI drive in GTSAM's wheel (``gtsam/Data``)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from quadnav.errors import IoError, QuadnavError
from quadnav.io.gtsam_kitti import (
    GPS_FILE,
    IMU_FILE,
    METADATA_FILE,
    gtsam_data_folder,
    read_gtsam_kitti,
)


def _folder() -> Path | None:
    try:
        folder = gtsam_data_folder()
    except QuadnavError:
        return None
    return folder if (folder / IMU_FILE).exists() else None


DATA = _folder()
needs_data = pytest.mark.skipif(DATA is None, reason="GTSAM's Data folder (KITTI files) absent")


def _data_lines(path: Path) -> int:
    return sum(1 for line in path.read_text().splitlines()[1:] if line.strip())


@needs_data
def test_the_drive_is_read_whole_in_si_units() -> None:
    assert DATA is not None
    d = read_gtsam_kitti(DATA)
    assert len(d.imu_t_ns) == _data_lines(DATA / IMU_FILE)
    assert len(d.gps_t_ns) == _data_lines(DATA / GPS_FILE)
    assert (np.diff(d.imu_t_ns) > 0).all() and (np.diff(d.gps_t_ns) > 0).all()
    # about 100 Hz and 1 Hz; the IMU's z reads gravity (z up), its rates are a car's
    assert np.median(np.diff(d.imu_t_ns)) == pytest.approx(1e7, rel=0.05)
    assert np.median(np.diff(d.gps_t_ns)) == pytest.approx(1e9, rel=0.05)
    assert np.median(d.accel_m_s2[:, 2]) == pytest.approx(9.8, abs=0.3)
    assert np.abs(d.gyro_rad_s).max() < 2.0
    speed = np.linalg.norm(np.diff(d.gps_p_m, axis=0), axis=1) / np.diff(d.gps_t_ns) * 1e9
    assert speed.max() < 40.0  # m/s: a car in town
    assert d.metadata.average_dt_s == pytest.approx(0.01, rel=0.05)
    assert d.metadata.accel_sigma > 0 and d.metadata.gyro_bias_sigma > 0
    s = d.imu_samples()[5]
    assert s.t_ns == d.imu_t_ns[5] and np.array_equal(s.accel_m_s2, d.accel_m_s2[5])
    fix = d.gps_samples(0.3)[7]
    assert fix.sigma_m == 0.3 and np.array_equal(fix.p_W_B, d.gps_p_m[7])


def _copy(tmp_path: Path) -> Path:
    assert DATA is not None
    for name in (GPS_FILE, METADATA_FILE):
        shutil.copy(DATA / name, tmp_path / name)
    head = (DATA / IMU_FILE).read_text().splitlines()[:50]
    (tmp_path / IMU_FILE).write_text("\n".join(head) + "\n")
    return tmp_path


@needs_data
@pytest.mark.parametrize(
    ("line", "said"),
    [("46536.4 0.01 1 2 3 4 5 x", "not a number"), ("46536.4 0.01 1 2 3 4 5", "expected 8 values")],
)
def test_a_corrupt_line_is_one_line_naming_the_file_and_line(
    tmp_path: Path, line: str, said: str
) -> None:
    folder = _copy(tmp_path)
    lines = (folder / IMU_FILE).read_text().splitlines()
    lines[10] = line
    (folder / IMU_FILE).write_text("\n".join(lines) + "\n")
    with pytest.raises(IoError) as exc:
        read_gtsam_kitti(folder)
    msg = str(exc.value)
    assert "\n" not in msg and f"{folder / IMU_FILE}:11:" in msg and said in msg


@needs_data
def test_time_going_back_names_its_line(tmp_path: Path) -> None:
    folder = _copy(tmp_path)
    lines = (folder / GPS_FILE).read_text().splitlines()
    lines[4], lines[5] = lines[5], lines[4]
    (folder / GPS_FILE).write_text("\n".join(lines) + "\n")
    with pytest.raises(IoError, match=rf"{GPS_FILE}:6: time does not increase"):
        read_gtsam_kitti(folder)


def test_a_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(IoError, match=rf"{METADATA_FILE}: file not found"):
        read_gtsam_kitti(tmp_path)
