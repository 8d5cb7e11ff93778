"""EurocWriter -> open_dataset and write_ros2_bag -> bag reader give back the same samples."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import IoError
from quadnav.geometry.camera import PinholeCamera
from quadnav.geometry.rotations import Pose
from quadnav.io.datasets import EurocWriter, VisualInertialDataset, open_dataset, write_ros2_bag
from quadnav.io.datasets.euroc import find_mav0
from quadnav.messages import ImageFrame, ImuSample
from quadnav.rig import CameraSpec, ImuNoiseModel, ImuSpec, Rig
from tests.io.test_datasets_euroc import assert_same_rig

W, H = 80, 60


def _rig(model: str, stereo: bool) -> Rig:
    K0 = np.array([[61.25, 0.0, 40.5], [0.0, 60.875, 29.75], [0.0, 0.0, 1.0]])
    d = (
        [0.0123, -0.00456, 1.7e-05, -3.3e-06]
        if model == "equidistant"
        else [-0.283, 0.0739, 0.000193, 1.76e-05]
    )
    R = Rotation.from_euler("zyx", [90.3, 0.7, -1.1], degrees=True)
    cams = [
        CameraSpec(
            name="cam0",
            camera=PinholeCamera(K0, np.array(d), W, H, model=model),  # type: ignore[arg-type]
            T_B_C=Pose(R, np.array([-0.0216, -0.0647, 0.0098])),
            rate_hz=20.0,
            time_offset_ns=-1_234_567,
            exposure_s=0.004,
        )
    ]
    if stereo:
        K1 = K0 + np.array([[0.3, 0, 1.1], [0, -0.2, 0.4], [0, 0, 0]])
        R1 = R * Rotation.from_euler("x", 0.2, degrees=True)
        cams.append(
            CameraSpec(
                name="cam1",
                camera=PinholeCamera(K1, np.array(d) * 1.01, W, H, model=model),  # type: ignore[arg-type]
                T_B_C=Pose(R1, np.array([-0.0198, 0.0454, 0.0079])),
                rate_hz=20.0,
                time_offset_ns=-1_234_567,
            )
        )
    noise = ImuNoiseModel(
        gyro_noise_density=1.6968e-04,
        gyro_random_walk=1.9393e-05,
        accel_noise_density=2.0e-3,
        accel_random_walk=3.0e-3,
    )
    return Rig(name="rt", cameras=tuple(cams), imu=ImuSpec(rate_hz=200.0, noise=noise))


def _write(root: Path, rig: Rig, seed: int = 0) -> dict[str, object]:
    """A 0.5 s sequence with random (not round) numbers; what was written, for comparison."""
    rng = np.random.default_rng(seed)
    images: dict[tuple[str, int], np.ndarray] = {}
    imu, gt = [], []
    t0 = 1_403_715_273_262_142_976
    with EurocWriter(root, rig) as w:
        for k in range(100):
            t = t0 + k * 5_000_000 + int(rng.integers(-3, 4))
            s = ImuSample(
                t_ns=t,
                gyro_rad_s=rng.normal(0, 0.3, 3),
                accel_m_s2=rng.normal(0, 3, 3) + [0, 0, 9.81],
            )
            w.add_imu(s)
            imu.append(s)
            if k % 10 == 0:
                for c in rig.camera_names:
                    img = rng.integers(0, 256, (H, W), dtype=np.uint8)
                    w.add_frame(c, t, img)
                    images[(c, t)] = img
                q = Rotation.random(random_state=k).as_quat()
                row = (
                    t,
                    rng.normal(0, 2, 3),
                    q,
                    rng.normal(0, 1, 3),
                    rng.normal(0, 1e-3, 3),
                    rng.normal(0, 1e-2, 3),
                )
                w.add_groundtruth(*row)
                gt.append(row)
    return {"images": images, "imu": imu, "gt": gt}


def _same_samples(
    ds: VisualInertialDataset, written: dict[str, object], *, gt_extras: bool = True
) -> None:
    images = written["images"]
    assert isinstance(images, dict)
    assert {(f.camera, f.t_ns) for f in ds.frames} == set(images)
    for f in ds.frames:
        np.testing.assert_array_equal(f.image(), images[(f.camera, f.t_ns)])  # bit-identical
    imu = written["imu"]
    assert isinstance(imu, list)
    assert list(ds.imu.t_ns) == [s.t_ns for s in imu]
    np.testing.assert_array_equal(ds.imu.gyro_rad_s, [s.gyro_rad_s for s in imu])
    np.testing.assert_array_equal(ds.imu.accel_m_s2, [s.accel_m_s2 for s in imu])
    gt, rows = ds.groundtruth, written["gt"]
    assert gt is not None and isinstance(rows, list)
    tr = gt.trajectory
    assert list(tr.t_ns) == [r[0] for r in rows]
    np.testing.assert_array_equal(tr.p_W_B, [r[1] for r in rows])
    q_in = np.array([r[2] for r in rows])
    np.testing.assert_allclose(
        tr.q_W_B_xyzw, q_in / np.linalg.norm(q_in, axis=1)[:, None], rtol=0, atol=1e-15
    )
    if gt_extras:
        assert (
            gt.v_W_B_m_s is not None
            and gt.gyro_bias_rad_s is not None
            and gt.accel_bias_m_s2 is not None
        )
        np.testing.assert_array_equal(gt.v_W_B_m_s, [r[3] for r in rows])
        np.testing.assert_array_equal(gt.gyro_bias_rad_s, [r[4] for r in rows])
        np.testing.assert_array_equal(gt.accel_bias_m_s2, [r[5] for r in rows])


CASES = [("radtan", False), ("radtan", True), ("equidistant", False), ("equidistant", True)]


@pytest.mark.parametrize(("model", "stereo"), CASES)
def test_euroc_writer_round_trip(tmp_path: Path, model: str, stereo: bool) -> None:
    rig = _rig(model, stereo)
    written = _write(tmp_path / "seq", rig)
    ds = open_dataset(tmp_path / "seq")
    assert ds.kind == "euroc" and not ds.issues
    assert_same_rig(ds.rig, rig, atol=1e-15)
    assert ds.rig.cameras[0].exposure_s == 0.004
    assert {f.exposure_s for f in ds.frames_of("cam0")} == {0.004}
    _same_samples(ds, written)
    # the Kalibr files beside mav0 describe the same rig (through T_cam_imu = T_B_C^-1)
    via_camchain = open_dataset(tmp_path / "seq", calibration=tmp_path / "seq" / "camchain.yaml")
    assert_same_rig(via_camchain.rig, rig, atol=1e-15)


@pytest.mark.parametrize(("model", "stereo"), CASES)
def test_ros2_bag_round_trip(tmp_path: Path, model: str, stereo: bool) -> None:
    rig = _rig(model, stereo)
    written = _write(tmp_path / "seq", rig, seed=1)
    bag = write_ros2_bag(open_dataset(tmp_path / "seq"), tmp_path / "bag")
    from_info = open_dataset(bag)  # calibration from the camera_info topics
    assert from_info.kind == "bag"
    assert_same_rig(from_info.rig, rig, atol=1e-15, lenses_only=True)
    with_calib = open_dataset(bag, calibration=tmp_path / "seq")
    assert_same_rig(with_calib.rig, rig, atol=1e-15)
    _same_samples(with_calib, written, gt_extras=False)
    items = list(with_calib.stream())
    assert [x.t_ns for x in items] == sorted(x.t_ns for x in items)
    assert sum(isinstance(x, ImageFrame) for x in items) == len(written["images"])  # type: ignore[arg-type]


def test_an_exception_leaves_no_readable_folder(tmp_path: Path) -> None:
    rig = _rig("radtan", False)
    root = tmp_path / "seq"
    with pytest.raises(RuntimeError), EurocWriter(root, rig) as w:
        w.add_frame("cam0", 10, np.zeros((H, W), np.uint8))
        raise RuntimeError("the renderer failed")
    assert not root.exists() and not (tmp_path / "seq.partial").exists()
    w2 = EurocWriter(root, rig)
    w2.add_frame("cam0", 10, np.zeros((H, W), np.uint8))  # never closed: still partial
    assert find_mav0(root) is None
    with pytest.raises(IoError, match="dataset not found"):
        open_dataset(root)
    w2.close()
    assert open_dataset(root).frames[0].t_ns == 10


def test_writer_refuses_bad_samples(tmp_path: Path) -> None:
    w = EurocWriter(tmp_path / "seq", _rig("radtan", False))
    w.add_frame("cam0", 100, np.zeros((H, W), np.uint8))
    with pytest.raises(IoError, match="t_ns 100 is not after the previous 100"):
        w.add_frame("cam0", 100, np.zeros((H, W), np.uint8))
    with pytest.raises(IoError, match="not one of the rig's"):
        w.add_frame("cam7", 200, np.zeros((H, W), np.uint8))
    with pytest.raises(IoError, match="must be uint8 60x80"):
        w.add_frame("cam0", 200, np.zeros((H, W + 1), np.uint8))
    with pytest.raises(IoError, match="q 4 finite"):
        w.add_groundtruth(300, [0, 0, np.nan], [0, 0, 0, 1])
    w.abort()
    with pytest.raises(IoError, match="already exists"):
        EurocWriter(tmp_path, _rig("radtan", False))
    (tmp_path / "file").write_text("")
    with pytest.raises(IoError, match=r"file/seq.partial: cannot be written \(Not a directory\)"):
        EurocWriter(tmp_path / "file" / "seq", _rig("radtan", False))


def test_ros2_bag_writer_sample_by_sample(tmp_path: Path) -> None:
    from quadnav.io.datasets import Ros2BagWriter

    rig = _rig("radtan", stereo=True)
    with pytest.raises(RuntimeError), Ros2BagWriter(tmp_path / "failed", rig) as w:
        w.add_frame("cam0", 5, np.zeros((H, W), np.uint8))
        raise RuntimeError("the renderer failed")
    assert not (tmp_path / "failed").exists() and not (tmp_path / "failed.partial").exists()
    rng = np.random.default_rng(9)
    pics = {}
    with Ros2BagWriter(tmp_path / "bag", rig) as w:
        for k in range(40):
            t = 2_000_000_000 + k * 5_000_000
            w.add_imu(
                ImuSample(
                    t_ns=t,
                    gyro_rad_s=np.array([k, 0.5, -1e-7]),
                    accel_m_s2=np.array([0.0, 1.0 / 3.0, 9.81]),
                )
            )
            if k % 10 == 0:
                for cam in ("cam0", "cam1"):
                    pics[(cam, t)] = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)  # colour: bgr8
                    w.add_frame(cam, t, pics[(cam, t)])
                w.add_groundtruth(t, [k, 2.0, 3.0], [0.0, 0.0, 0.6, 0.8])
    ds = open_dataset(tmp_path / "bag")
    assert_same_rig(ds.rig, rig, atol=1e-15, lenses_only=True)
    assert ds.rig.baseline_m == pytest.approx(
        abs((rig.cameras[0].T_B_C.inverse() @ rig.cameras[1].T_B_C).p_A_B[0]), rel=1e-12
    )
    assert len(ds.imu) == 40
    assert ds.imu.accel_m_s2[7, 1] == 1.0 / 3.0 and ds.imu.gyro_rad_s[3, 2] == -1e-7
    assert {(f.camera, f.t_ns) for f in ds.frames} == set(pics)
    for f in ds.frames:
        np.testing.assert_array_equal(f.image(), pics[(f.camera, f.t_ns)])
    gt = ds.groundtruth
    assert gt is not None and gt.trajectory.p_W_B[2].tolist() == [20.0, 2.0, 3.0]


def test_kalibr_and_openvins_files_beside_mav0(tmp_path: Path) -> None:
    """Kalibr's files parse with PyYAML, OpenVINS' with OpenCV's FileStorage, and both say the
    rig's calibration (T_cam_imu = T_B_C^-1, T_imu_cam = T_B_C)."""
    import cv2
    import yaml

    rig = _rig("equidistant", stereo=True)
    _write(tmp_path / "seq", rig)
    kalibr = yaml.safe_load((tmp_path / "seq" / "camchain.yaml").read_text())
    T_cam_imu = np.array(kalibr["cam1"]["T_cam_imu"])
    np.testing.assert_allclose(T_cam_imu, rig.cameras[1].T_B_C.inverse().matrix(), atol=1e-15)
    assert kalibr["cam1"]["distortion_model"] == "equidistant"
    imu = yaml.safe_load((tmp_path / "seq" / "imu.yaml").read_text())["imu0"]
    assert imu["gyroscope_random_walk"] == 1.9393e-05 and imu["update_rate"] == 200.0
    fs = cv2.FileStorage(str(tmp_path / "seq" / "kalibr_imucam_chain.yaml"), cv2.FILE_STORAGE_READ)
    node = fs.getNode("cam1").getNode("T_imu_cam")
    T_imu_cam = np.array([[node.at(i).at(j).real() for j in range(4)] for i in range(4)])
    np.testing.assert_allclose(T_imu_cam, rig.cameras[1].T_B_C.matrix(), atol=1e-15)
    intr = fs.getNode("cam1").getNode("intrinsics")
    assert [intr.at(i).real() for i in range(4)] == [61.55, 60.675, 41.6, 30.15]
    fs_imu = cv2.FileStorage(str(tmp_path / "seq" / "kalibr_imu_chain.yaml"), cv2.FILE_STORAGE_READ)
    assert fs_imu.getNode("imu0").getNode("accelerometer_noise_density").real() == 2.0e-3
    ours = open_dataset(tmp_path / "seq", calibration=tmp_path / "seq" / "kalibr_imucam_chain.yaml")
    assert_same_rig(ours.rig, rig, atol=1e-15)


def test_a_written_bag_names_its_storage_after_itself(tmp_path: Path) -> None:
    """ROS 2 tools find the storage through metadata.yaml, people by its name: bag.db3, not the
    name of the folder it was made in."""
    from quadnav.io.datasets import Ros2BagWriter
    from quadnav.messages import ImuSample
    from quadnav.rig import rig_named

    with Ros2BagWriter(tmp_path / "flight", rig_named("thesis003_sim")) as w:
        w.add_imu(ImuSample(t_ns=1, gyro_rad_s=np.zeros(3), accel_m_s2=np.zeros(3)))
    assert sorted(p.name for p in (tmp_path / "flight").iterdir()) == [
        "flight.db3",
        "metadata.yaml",
    ]
    assert "flight.db3" in (tmp_path / "flight" / "metadata.yaml").read_text()
    assert not (tmp_path / "flight.partial").exists()


def test_a_bags_repeated_and_out_of_order_imu_messages_are_rejected_and_counted(
    tmp_path: Path,
) -> None:
    """Issue 21, item 7, in the bag reader: messages in the bag's order, as a csv's rows."""
    from quadnav.io.datasets import Ros2BagWriter

    rig = _rig("radtan", stereo=False)
    stamps = [1_000, 2_000, 2_000, 3_000, 1_500, 4_000, 10**15, 5_000]
    with Ros2BagWriter(tmp_path / "bag", rig) as w:
        w.add_frame("cam0", 1_000, np.zeros((H, W), np.uint8))
        for k, t in enumerate(stamps):  # received in this order, stamped out of it
            msg = w.m.imu(t, np.zeros(3), np.zeros(3))
            w._write("/imu0", "sensor_msgs/msg/Imu", 2_000 + k, msg)
    ds = open_dataset(tmp_path / "bag")
    assert ds.imu.t_ns.tolist() == [1_000, 2_000, 3_000, 4_000, 5_000]
    assert ds.issues.counts == {"IMU messages repeated": 1, "IMU messages out of order": 2}
