"""EuRoC ASL reading: the real start of V1_01_easy (../shared/data/euroc_micro) and bad input."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from quadnav.errors import IoError, QuadnavError, SampleError
from quadnav.io.datasets import EurocWriter, VisualInertialDataset, open_dataset
from quadnav.messages import ImageFrame, ImuSample
from quadnav.rig import Rig, euroc
from tests.shared_data import SHARED, needs

EUROC_MICRO = SHARED / "euroc_micro"


def assert_same_rig(a: Rig, b: Rig, *, atol: float = 1e-12, lenses_only: bool = False) -> None:
    """Two rigs calibrated alike: lenses, rates and, unless ``lenses_only``, the cameras' poses
    and time offsets and the IMU's noise."""
    assert a.camera_names == b.camera_names
    for ca, cb in zip(a.cameras, b.cameras, strict=True):
        assert ca.camera.model == cb.camera.model
        assert (ca.camera.width, ca.camera.height) == (cb.camera.width, cb.camera.height)
        np.testing.assert_allclose(ca.camera.K, cb.camera.K, rtol=0, atol=atol)
        np.testing.assert_allclose(ca.camera.dist, cb.camera.dist, rtol=0, atol=atol)
        if not lenses_only:
            np.testing.assert_allclose(ca.T_B_C.matrix(), cb.T_B_C.matrix(), rtol=0, atol=atol)
            assert ca.time_offset_ns == cb.time_offset_ns
        assert ca.rate_hz == pytest.approx(cb.rate_hz, rel=1e-9)
    assert (a.imu is None) == (b.imu is None)
    if a.imu is not None and b.imu is not None and not lenses_only:
        assert a.imu.rate_hz == pytest.approx(b.imu.rate_hz, rel=1e-9)
        for name in (
            "gyro_noise_density",
            "gyro_random_walk",
            "accel_noise_density",
            "accel_random_walk",
        ):
            assert getattr(a.imu.noise, name) == pytest.approx(
                getattr(b.imu.noise, name), rel=1e-12
            )


@pytest.fixture(scope="module")
def micro() -> VisualInertialDataset:
    if not EUROC_MICRO.exists():
        pytest.skip(f"shared test data not found at {EUROC_MICRO}")
    return open_dataset(EUROC_MICRO)


@needs(EUROC_MICRO)
def test_euroc_micro_calibration_is_the_euroc_rig(micro: VisualInertialDataset) -> None:
    assert micro.kind == "euroc"
    assert_same_rig(micro.rig, euroc(), atol=1e-15)
    assert micro.rig.baseline_m == pytest.approx(0.110, abs=0.001)


@needs(EUROC_MICRO)
def test_euroc_micro_frames_imu_and_groundtruth(micro: VisualInertialDataset) -> None:
    assert len(micro.frames_of("cam0")) == 95 and len(micro.frames_of("cam1")) == 95
    # cam1/data.csv lists four images past the 95th that the folder does not hold: counted
    assert micro.issues.counts == {"missing images": 4}
    assert "cam1/data.csv:97" in micro.issues.named[0]
    assert [f.t_ns for f in micro.frames_of("cam0")] == [f.t_ns for f in micro.frames_of("cam1")]
    assert len(micro.imu) == 29120
    assert micro.imu[0].t_ns == 1403715273262142976
    np.testing.assert_array_equal(
        micro.imu[0].accel_m_s2, [9.0874956666666655, 0.13075533333333333, -3.6938381666666662]
    )
    gt = micro.groundtruth
    assert gt is not None and gt.source == "state_groundtruth_estimate0" and len(gt) == 2895
    assert gt.trajectory.t_ns[0] == 1403715273262142976
    np.testing.assert_array_equal(gt.trajectory.p_W_B[0], [0.878895, 2.1834, 0.948427])
    np.testing.assert_allclose(
        gt.trajectory.q_W_B_xyzw[0], [-0.824237, -0.106942, -0.551702, 0.069433], atol=1e-6
    )
    assert (
        gt.gyro_bias_rad_s is not None
        and gt.accel_bias_m_s2 is not None
        and gt.v_W_B_m_s is not None
    )
    np.testing.assert_array_equal(gt.accel_bias_m_s2[0], [-0.0180115, 0.0659796, 0.0309774])
    img = micro.frames[0].image()
    assert img.shape == (480, 752) and img.dtype == np.uint8


@needs(EUROC_MICRO)
def test_euroc_micro_stream_is_time_ordered_imu_first(micro: VisualInertialDataset) -> None:
    items = list(micro.stream())
    assert len(items) == 190 + 29120
    stamps = [x.t_ns for x in items]
    assert stamps == sorted(stamps)
    # the first camera stamp is also an IMU stamp: the IMU sample comes first, then cam0, cam1
    t0 = micro.frames[0].t_ns
    at_t0 = [x for x in items if x.t_ns == t0]
    assert isinstance(at_t0[0], ImuSample)
    assert [x.camera for x in at_t0[1:] if isinstance(x, ImageFrame)] == ["cam0", "cam1"]
    frames = [x for x in items if isinstance(x, ImageFrame)]
    assert len(frames) == 190


def test_frames_hold_no_pixels_until_asked(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import quadnav.io.datasets.euroc as euroc_mod

    root = _tiny(tmp_path / "seq", n_frames=30)
    calls: list[str] = []
    real = euroc_mod.load_image

    def counting(path: str) -> np.ndarray:
        calls.append(path)
        return real(path)

    monkeypatch.setattr(euroc_mod, "load_image", counting)
    ds = open_dataset(root)
    n = sum(1 for _ in ds.stream())
    assert n == 30 + len(ds.imu) and calls == []
    img = ds.frames[7].image()
    assert len(calls) == 1 and calls[0].endswith(f"{ds.frames[7].t_ns}.png")
    np.testing.assert_array_equal(img, _pattern(7))


def _pattern(k: int, shape: tuple[int, int] = (48, 64)) -> np.ndarray:
    rng = np.random.default_rng(k)
    return rng.integers(0, 256, size=shape, dtype=np.uint8)


def _tiny_rig() -> Rig:
    from quadnav.geometry.camera import PinholeCamera
    from quadnav.geometry.rotations import Pose
    from quadnav.rig import CameraSpec, ImuNoiseModel, ImuSpec

    K = np.array([[50.0, 0.0, 32.0], [0.0, 50.0, 24.0], [0.0, 0.0, 1.0]])
    cam = CameraSpec(
        name="cam0",
        camera=PinholeCamera(K, np.array([-0.1, 0.01, 0.0, 0.0]), 64, 48),
        T_B_C=Pose.identity(),
        rate_hz=20.0,
    )
    return Rig(
        name="tiny",
        cameras=(cam,),
        imu=ImuSpec(rate_hz=200.0, noise=ImuNoiseModel.euroc_adis16448()),
    )


def _tiny(root: Path, n_frames: int = 5) -> Path:
    """A small EuRoC folder written by EurocWriter: frames at 20 Hz, IMU at 200 Hz, ground truth."""
    with EurocWriter(root, _tiny_rig()) as w:
        for k in range(n_frames * 10):
            t = 1_000_000_000 + k * 5_000_000
            w.add_imu(
                ImuSample(
                    t_ns=t,
                    gyro_rad_s=np.array([0.01 * k, 0.0, 0.0]),
                    accel_m_s2=np.array([0.0, 0.0, 9.81]),
                )
            )
            if k % 10 == 0:
                w.add_frame("cam0", t, _pattern(k // 10))
                w.add_groundtruth(t, [0.1 * k, 0, 0], [0, 0, 0, 1])
    return root


def _edit(path: Path, line: int, text: str | None) -> None:
    """Replace (or with None delete) one 1-based line of a file."""
    lines = path.read_text().splitlines()
    if text is None:
        del lines[line - 1]
    else:
        lines[line - 1] = text
    path.write_text("\n".join(lines) + "\n")


def _error(root: Path) -> str:
    with pytest.raises(IoError) as info:
        open_dataset(root)
    msg = str(info.value)
    assert "\n" not in msg
    return msg


def test_missing_folder_and_csv(tmp_path: Path) -> None:
    assert "not found" in _error(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    assert "not a dataset quadnav reads" in _error(tmp_path / "empty")
    root = _tiny(tmp_path / "seq")
    (root / "mav0" / "imu0" / "data.csv").unlink()
    assert "imu0/data.csv: no such file" in _error(root)
    shutil.rmtree(root / "mav0" / "cam0")
    assert "no cam0/ folder" in _error(root)


@pytest.mark.parametrize(
    ("key", "new", "expected"),
    [
        ("intrinsics", "intrinsics: [50.0, 50.0, 32.0]", "intrinsics must have 4 numbers, got 3"),
        ("T_BS", None, "missing key 'T_BS'"),
        ("distortion_model", "distortion_model: kannala", "distortion model 'kannala'"),
        ("resolution", "resolution: [64, abc]", "resolution must be numbers"),
        ("rate_hz", "rate_hz: [20", "cam0/sensor.yaml:"),
    ],
)
def test_malformed_sensor_yaml(tmp_path: Path, key: str, new: str | None, expected: str) -> None:
    root = _tiny(tmp_path / "seq")
    path = root / "mav0" / "cam0" / "sensor.yaml"
    lines = path.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith(key))
    if new is None:  # the key and its indented block
        end = k + 1
        while end < len(lines) and lines[end].startswith("  "):
            end += 1
        del lines[k:end]
    else:
        lines[k] = new
    path.write_text("\n".join(lines) + "\n")
    msg = _error(root)
    assert "sensor.yaml" in msg and expected in msg


IMU0 = 1_000_000_000  # the first IMU stamp of _tiny; its rows 5 ms apart, row r on line r + 2


def test_bad_imu_rows_are_rejected_and_counted(tmp_path: Path) -> None:
    """Issue 21, item 7: one bad row refused the whole dataset. Each kind of damage costs its
    own row, a stamp far in the future included, and is counted."""
    root = _tiny(tmp_path / "seq")
    imu = root / "mav0" / "imu0" / "data.csv"
    rows = imu.read_text().splitlines()
    _edit(imu, 4, f"{IMU0 + 10_000_000},0.1,0.2")  # too few columns
    _edit(imu, 6, rows[4])  # line 6 repeats line 5
    _edit(imu, 8, rows[2])  # line 8 goes back to line 3's stamp
    _edit(imu, 10, "12x4,0,0,0,0,0,9.81")  # not integer nanoseconds
    _edit(imu, 12, f"{IMU0 + 10**12},0,0,0,0,0,9.81")  # 1000 s ahead of its neighbours
    ds = open_dataset(root)
    assert ds.issues.counts == {
        "IMU rows unreadable": 2, "IMU rows repeated": 1, "IMU rows out of order": 2,
    }  # fmt: skip
    assert ds.issues.named[0] == "imu0/data.csv:4: IMU rows unreadable"
    lost = {IMU0 + 5_000_000 * r for r in (2, 4, 6, 8, 10)}  # rows of lines 4, 6, 8, 10, 12
    assert ds.imu.t_ns.tolist() == [
        IMU0 + 5_000_000 * r for r in range(50) if IMU0 + 5_000_000 * r not in lost
    ]
    assert "rejected" in repr(ds) and "IMU rows out of order" in ds.issues.summary()


@pytest.mark.parametrize(
    ("stamps", "faults"),
    [
        ([1, 2, 3], [0, 0, 0]),
        ([1, 2, 2, 3], [0, 0, 1, 0]),  # the repeat is the second
        ([1, 2, 9, 3, 4], [0, 0, 2, 0, 0]),  # a jump ahead costs itself, not the rest
        ([9, 1, 2], [2, 0, 0]),  # even as the first row
        ([1, 3, 0, 4], [0, 0, 2, 0]),  # a step back before the last kept row
        ([1, 2, 3, 3, 3, 1, 4], [0, 0, 0, 1, 1, 2, 0]),
    ],
)
def test_order_faults_cost_one_row_per_bad_row(stamps: list[int], faults: list[int]) -> None:
    from quadnav.io.datasets.types import order_faults

    assert order_faults(np.array(stamps, dtype=np.int64)).tolist() == faults


def test_bad_image_rows_are_rejected_and_counted_as_the_cameras(tmp_path: Path) -> None:
    root = _tiny(tmp_path / "seq")
    cams = root / "mav0" / "cam0" / "data.csv"
    rows = cams.read_text().splitlines()
    _edit(cams, 3, "12x4,foo.png")
    _edit(cams, 5, rows[3])  # repeats line 4
    ds = open_dataset(root)
    assert ds.issues.counts == {"image rows unreadable": 1, "image rows repeated": 1}
    assert ds.issues.camera_counts == {"cam0": ds.issues.counts}
    assert len(ds.frames) == 5 - 2
    assert not ds.issues.for_cameras(["cam1"]) and ds.issues.for_cameras(["cam0"]) == ds.issues


def test_without_an_issue_log_a_bad_row_is_a_one_line_error(tmp_path: Path) -> None:
    from quadnav.io.datasets.files import read_table

    root = _tiny(tmp_path / "seq")
    imu = root / "mav0" / "imu0" / "data.csv"
    rows = imu.read_text().splitlines()
    _edit(imu, 4, rows[2])
    with pytest.raises(IoError, match=r"imu0/data.csv:4: timestamp 1005000000 repeats"):
        read_table(imu, 6, None, "IMU rows")


def test_nan_imu_rows_are_rejected_and_counted(tmp_path: Path) -> None:
    root = _tiny(tmp_path / "seq")
    imu = root / "mav0" / "imu0" / "data.csv"
    _edit(imu, 5, "1015000000,nan,0.0,0.0,0.0,0.0,9.81")
    _edit(imu, 9, "1035000000,0.1,0.0,0.0,0.0,,9.81")
    ds = open_dataset(root)
    assert len(ds.imu) == 50 - 2 and 1015000000 not in ds.imu.t_ns
    assert ds.issues.counts == {"IMU rows with a NaN": 2}
    assert ds.issues.named[0] == "imu0/data.csv:5: IMU rows with a NaN"


def test_missing_and_corrupt_images(tmp_path: Path) -> None:
    root = _tiny(tmp_path / "seq")
    data = root / "mav0" / "cam0" / "data"
    names = sorted(p.name for p in data.iterdir())
    (data / names[1]).unlink()
    (data / names[2]).write_bytes(b"\x89PNG\r\n\x1a\n broken")
    ds = open_dataset(root)
    assert len(ds.frames) == 4 and ds.issues.counts == {"missing images": 1}
    assert f"cam0/data.csv:3 ({names[1]})" in ds.issues.named[0]
    with pytest.raises(SampleError) as info:
        ds.frames[1].image()
    assert names[2] in str(info.value) and "corrupt" in str(info.value)
    assert isinstance(info.value, QuadnavError)
    checked = ds.verified()  # decodes each image once: the corrupt one rejected and counted
    assert [f.t_ns for f in checked.frames] == [ds.frames[0].t_ns, *(f.t_ns for f in ds.frames[2:])]
    assert checked.issues.counts == {"missing images": 1, "unreadable images": 1}
    assert names[2] in checked.issues.named[1]


def test_vicon0_and_leica0_ground_truth(tmp_path: Path) -> None:
    """Without state_groundtruth_estimate0: vicon0's poses of the marker body, moved to the
    body frame by its T_BS; else leica0's prism positions (orientation unknown)."""
    root = _tiny(tmp_path / "seq")
    mav0 = root / "mav0"
    shutil.rmtree(mav0 / "state_groundtruth_estimate0")
    (mav0 / "vicon0").mkdir()
    (mav0 / "vicon0" / "data.csv").write_text(
        "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []\n"
        "1000000000,1.0,2.0,3.0,0.7071067811865476,0.0,0.0,0.7071067811865476\n"
        "1050000000,1.5,2.0,3.0,1.0,0.0,0.0,0.0\n"
    )
    # the marker S sits 0.1 m along the body's x: T_BS translation (0.1, 0, 0)
    (mav0 / "vicon0" / "sensor.yaml").write_text(
        "%YAML:1.0\nsensor_type: visual\nT_BS:\n  cols: 4\n  rows: 4\n"
        "  data: [1.0, 0.0, 0.0, 0.1, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]\n"
    )
    gt = open_dataset(root).groundtruth
    assert (
        gt is not None and gt.source == "vicon0" and gt.orientation_known and gt.v_W_B_m_s is None
    )
    # yaw 90 deg: the body origin is 0.1 m behind the marker along the body x = world y
    np.testing.assert_allclose(gt.trajectory.p_W_B, [[1.0, 1.9, 3.0], [1.4, 2.0, 3.0]], atol=1e-12)
    shutil.rmtree(mav0 / "vicon0")
    (mav0 / "leica0").mkdir()
    (mav0 / "leica0" / "data.csv").write_text(
        "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m]\n1000000000,4.0,5.0,6.0\n"
    )
    gt = open_dataset(root).groundtruth
    assert gt is not None and gt.source == "leica0" and not gt.orientation_known
    np.testing.assert_array_equal(gt.trajectory.p_W_B, [[4.0, 5.0, 6.0]])
