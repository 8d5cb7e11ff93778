"""TUM-VI (EuRoC export + dso/camchain.yaml), KITTI odometry and ROS 1/2 bag fixtures, built in
the formats' own layouts in a temporary folder."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from quadnav.errors import IoError
from quadnav.io.datasets import open_dataset
from quadnav.io.datasets.kalibr import write_camchain
from quadnav.messages import ImageFrame, ImuSample
from tests.shared_data import SHARED

# TUM-VI's calibration values in its layout (dataset-*_512_16/dso/camchain.yaml: Kalibr,
# equidistant); the reader makes a rotation block exactly orthonormal, hence atol 1e-4 below
TUMVI_T_CAM_IMU = {
    "cam0": [
        [-0.9995250378696743, 0.029615343885863205, -0.008522328211654736, 0.04727988224914392],
        [0.0075019185074052044, -0.03439736061393144, -0.9993800792498829, -0.047443232143367084],
        [-0.02989013031643309, -0.9989693790823061, 0.034221515061512936, -0.0681999605066297],
        [0.0, 0.0, 0.0, 1.0],
    ],
    "cam1": [
        [-0.9995110484978581, 0.030299116376600627, -0.0077218830287333565, -0.053697434688869734],
        [0.008104079263822521, 0.012511643720192351, -0.9998888851620987, -0.046131737923635924],
        [-0.030095572218953283, -0.9994625667418545, -0.012751072156480147, -0.07149261284116752],
        [0.0, 0.0, 0.0, 1.0],
    ],
}
TUMVI_LENS = {
    "cam0": (
        [190.97847715128717, 190.9733070521226, 254.93170605935475, 256.8974428996504],
        [
            0.0034823894022493434,
            0.0007150348452162257,
            -0.0020532361418706202,
            0.00020293673591811182,
        ],
    ),
    "cam1": (
        [190.44236969414825, 190.4344384721956, 252.59949716835982, 254.91723064636983],
        [0.0034003170790442797, 0.001766278153469831, -0.00266312569781606, 0.0003299517423931039],
    ),
}
T0 = 1520530308199447626


def _tumvi(root: Path, n: int = 6) -> Path:
    mav0 = root / "mav0"
    for cam in ("cam0", "cam1"):
        (mav0 / cam / "data").mkdir(parents=True)
        rows = ["#timestamp [ns],filename"]
        for k in range(n):
            t = T0 + k * 50_000_000
            img16 = (np.arange(512 * 512, dtype=np.uint32).reshape(512, 512) * 7 + k * 256) % 65536
            cv2.imwrite(str(mav0 / cam / "data" / f"{t}.png"), img16.astype(np.uint16))
            rows.append(f"{t},{t}.png")
        (mav0 / cam / "data.csv").write_text("\n".join(rows) + "\n")
    (mav0 / "imu0").mkdir()
    imu = [
        "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"
    ]
    imu += [
        f"{T0 - 2_000_000 + k * 5_000_000},-0.0{k % 9},0.01,0.02,9.{k % 7},0.3,-0.1"
        for k in range(n * 10)
    ]
    (mav0 / "imu0" / "data.csv").write_text("\n".join(imu) + "\n")
    (mav0 / "mocap0").mkdir()
    mocap = [
        "#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []"
    ]
    mocap += [f"{T0 + k * 10_000_000},0.{k},1.5,-0.25,0.5,0.5,-0.5,0.5" for k in range(n * 5)]
    (mav0 / "mocap0" / "data.csv").write_text("\n".join(mocap) + "\n")
    (root / "dso").mkdir()
    text = ""
    for cam, T in TUMVI_T_CAM_IMU.items():
        intr, dist = TUMVI_LENS[cam]
        text += f"{cam}:\n  T_cam_imu:\n" + "".join(f"  - {row}\n" for row in T)
        text += f"  camera_model: pinhole\n  distortion_coeffs: {dist}\n  distortion_model: equidistant\n"
        text += f"  intrinsics: {intr}\n  resolution: [512, 512]\n  rostopic: /{cam}/image_raw\n"
        if cam == "cam0":
            text += "  timeshift_cam_imu: 0.0012\n"
    (root / "dso" / "camchain.yaml").write_text(text)
    (root / "dso" / "imu_config.yaml").write_text(
        "accelerometer_noise_density: 0.0028     # m/s^1.5\naccelerometer_random_walk:   0.00086\n"
        "gyroscope_noise_density:     0.00016    # rad/s^0.5\ngyroscope_random_walk:       0.000022\n"
        "rostopic:                    /imu0\nupdate_rate:                 200.0\n"
    )
    return root


def test_tumvi_folder(tmp_path: Path) -> None:
    root = _tumvi(tmp_path / "dataset-corridor1_512_16")
    for cam in ("cam0", "cam1"):  # a sensor.yaml without calibration: dso/camchain.yaml wins
        (root / "mav0" / cam / "sensor.yaml").write_text("%YAML:1.0\nsensor_type: camera\n")
    ds = open_dataset(root)
    assert ds.kind == "tumvi" and ds.rig.camera_names == ["cam0", "cam1"]
    for spec in ds.rig.cameras:
        intr, dist = TUMVI_LENS[spec.name]
        assert spec.camera.model == "equidistant" and (spec.camera.width, spec.camera.height) == (
            512,
            512,
        )
        assert [
            spec.camera.K[0, 0],
            spec.camera.K[1, 1],
            spec.camera.K[0, 2],
            spec.camera.K[1, 2],
        ] == intr
        assert spec.camera.dist.tolist() == dist
        np.testing.assert_allclose(
            spec.T_B_C.inverse().matrix(), TUMVI_T_CAM_IMU[spec.name], atol=1e-4
        )
        assert spec.rate_hz == 20.0
    assert ds.rig.cameras[0].time_offset_ns == 1_200_000 and ds.rig.cameras[1].time_offset_ns == 0
    assert ds.rig.baseline_m == pytest.approx(0.1010, abs=0.0005)  # TUM-VI's stereo baseline
    imu = ds.rig.imu
    assert imu is not None and imu.rate_hz == 200.0
    assert (imu.noise.gyro_noise_density, imu.noise.accel_random_walk) == (0.00016, 0.00086)
    assert len(ds.frames) == 12 and len(ds.imu) == 60
    gt = ds.groundtruth
    assert gt is not None and gt.source == "mocap0" and len(gt) == 30 and gt.v_W_B_m_s is None
    np.testing.assert_allclose(gt.trajectory.q_W_B_xyzw[0], [0.5, -0.5, 0.5, 0.5])
    # 16-bit pictures keep their high byte
    img = ds.frames_of("cam1")[2].image()
    expected = ((np.arange(512 * 512).reshape(512, 512) * 7 + 2 * 256) % 65536) >> 8
    assert img.dtype == np.uint8 and np.array_equal(img, expected)
    # the camera-IMU offset: frames stay at their stamps unless asked
    raw = [x.t_ns for x in ds.stream() if isinstance(x, ImageFrame) and x.camera == "cam0"]
    moved = [
        x.t_ns
        for x in ds.stream(apply_time_offset=True)
        if isinstance(x, ImageFrame) and x.camera == "cam0"
    ]
    assert raw[0] == T0 and moved == [t + 1_200_000 for t in raw]
    stamps = [x.t_ns for x in ds.stream(apply_time_offset=True)]
    assert stamps == sorted(stamps)


KITTI_CALIB = """P0: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 0.000000000000e+00 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P1: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 -3.861448000000e+02 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00
P2: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 4.538225000000e+01 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 -1.130887000000e-01 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 3.779761000000e-03
P3: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 -3.372877000000e+02 0.000000000000e+00 7.188560000000e+02 1.852157000000e+02 2.369057000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 4.915215000000e-03
Tr: 4.276802385584e-04 -9.999672484946e-01 -8.084491683471e-03 -1.198459927713e-02 -7.210626507497e-03 8.081198471645e-03 -9.999413164504e-01 -5.403984729748e-02 9.999738645903e-01 4.859485810390e-04 -7.206933692422e-03 -2.921968648686e-01
"""
KITTI_TIMES = [0.0, 0.1036610, 0.2073220, 0.3109820, 0.4146430]


def test_tumvi_bad_imu_and_mocap_rows_are_rejected_and_counted(tmp_path: Path) -> None:
    """Issue 21, item 7: TUM-VI's IMU rows are read as EuRoC's; one bad row refused the folder."""
    root = _tumvi(tmp_path / "dataset-corridor1_512_16")
    imu = root / "mav0" / "imu0" / "data.csv"
    rows = imu.read_text().splitlines()
    rows[10] = rows[9]  # repeated
    rows[20] = rows[20].replace(",", ";")  # one column
    imu.write_text("\n".join(rows) + "\n")
    mocap = root / "mav0" / "mocap0" / "data.csv"
    rows = mocap.read_text().splitlines()
    rows[5] = rows[2]  # back in time
    mocap.write_text("\n".join(rows) + "\n")
    ds = open_dataset(root)
    assert len(ds.imu) == 60 - 2 and ds.groundtruth is not None and len(ds.groundtruth) == 30 - 1
    assert ds.issues.counts == {
        "IMU rows repeated": 1, "IMU rows unreadable": 1, "ground-truth rows out of order": 1,
    }  # fmt: skip


def _kitti(root: Path) -> Path:
    for cam in ("image_0", "image_1"):
        (root / cam).mkdir(parents=True)
        for k in range(len(KITTI_TIMES)):
            cv2.imwrite(
                str(root / cam / f"{k:06d}.png"),
                np.full((376, 1241), 10 * k + (cam == "image_1"), np.uint8),
            )
    (root / "calib.txt").write_text(KITTI_CALIB)
    (root / "times.txt").write_text("".join(f"{t:e}\n" for t in KITTI_TIMES))
    return root


def test_kitti_sequence(tmp_path: Path) -> None:
    root = _kitti(tmp_path / "sequences" / "00")
    ds = open_dataset(root)
    assert ds.kind == "kitti" and ds.rig.imu is None and len(ds.imu) == 0
    assert ds.rig.camera_names == ["cam0", "cam1"]
    c0, c1 = ds.rig.cameras
    assert (c0.camera.width, c0.camera.height) == (1241, 376)
    assert (
        c0.camera.K[0, 0] == 718.856 and c0.camera.K[0, 2] == 607.1928 and not c0.camera.distorted
    )
    assert ds.rig.baseline_m == pytest.approx(386.1448 / 718.856, rel=1e-12)  # 0.537 m
    np.testing.assert_array_equal(c1.T_B_C.p_A_B, [386.1448 / 718.856, 0.0, 0.0])
    assert [f.t_ns for f in ds.frames_of("cam0")] == [
        0,
        103_661_000,
        207_322_000,
        310_982_000,
        414_643_000,
    ]
    assert [f.camera for f in ds.frames[:4]] == ["cam0", "cam1", "cam0", "cam1"]
    assert ds.frames[3].image()[0, 0] == 11 and ds.groundtruth is None
    assert c0.rate_hz == pytest.approx(9.65, abs=0.01)


def test_kitti_ground_truth_from_a_poses_file(tmp_path: Path) -> None:
    real = SHARED / "evo" / "KITTI_00_gt.txt"
    if not real.exists():
        pytest.skip(f"shared test data not found at {real}")
    poses = tmp_path / "00.txt"
    poses.write_text("".join(real.read_text().splitlines(keepends=True)[: len(KITTI_TIMES)]))
    ds = open_dataset(_kitti(tmp_path / "00"), groundtruth=poses)
    gt = ds.groundtruth
    assert gt is not None and list(gt.trajectory.t_ns) == [f.t_ns for f in ds.frames_of("cam0")]
    np.testing.assert_allclose(gt.trajectory.p_W_B[2], [-9.374345e-02, -5.676064e-02, 1.716275e00])
    poses.write_text(poses.read_text() + real.read_text().splitlines()[10] + "\n")
    with pytest.raises(IoError, match="6 poses for 5 times"):
        open_dataset(tmp_path / "00", groundtruth=poses)


def test_kitti_bad_calib_and_times(tmp_path: Path) -> None:
    root = _kitti(tmp_path / "00")
    (root / "calib.txt").write_text(KITTI_CALIB.replace("P1: 7.188560000000e+02 ", "P1: "))
    with pytest.raises(IoError, match=r"calib.txt:2: P1 must be 12 finite numbers, got 11"):
        open_dataset(root)
    (root / "calib.txt").write_text(KITTI_CALIB)
    (root / "times.txt").write_text("0.0\n0.2\n0.1\n0.3\n0.4\n")
    with pytest.raises(IoError, match=r"times.txt:3: time 0.1 is not after"):
        open_dataset(root)


# --- bags ----------------------------------------------------------------------------------


def _header(ts: Any, t_ns: int, ros1: bool) -> Any:
    stamp = ts.types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
    if ros1:
        return ts.types["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="cam")
    return ts.types["std_msgs/msg/Header"](stamp=stamp, frame_id="cam")


def _image(ts: Any, t: int, ros1: bool, enc: str, px: np.ndarray) -> Any:
    h, w = px.shape[:2]
    data = px.astype(">u2").view(np.uint8).ravel() if enc == "mono16" else px.ravel()
    return ts.types["sensor_msgs/msg/Image"](
        header=_header(ts, t, ros1),
        height=h,
        width=w,
        encoding=enc,
        is_bigendian=1 if enc == "mono16" else 0,
        step=data.size // h,
        data=data,
    )


def _info(ts: Any, t: int, ros1: bool, model: str, tx: float) -> Any:
    K = [300.0, 0.0, 32.5, 0.0, 301.0, 24.5, 0.0, 0.0, 1.0]
    P = [300.0, 0.0, 32.5, tx, 0.0, 301.0, 24.5, 0.0, 0.0, 0.0, 1.0, 0.0]
    D = np.array([0.01, -0.002, 0.0003, -0.0004] + ([0.00005] if model == "plumb_bob" else []))
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    names = ("D", "K", "R", "P") if ros1 else ("d", "k", "r", "p")
    fields = dict(zip(names, (D, np.array(K), np.eye(3).ravel(), np.array(P)), strict=True))
    return ts.types["sensor_msgs/msg/CameraInfo"](
        header=_header(ts, t, ros1),
        height=48,
        width=64,
        distortion_model=model,
        binning_x=0,
        binning_y=0,
        roi=roi,
        **fields,
    )


def _imu(ts: Any, t: int, ros1: bool, k: int) -> Any:
    V, Q = ts.types["geometry_msgs/msg/Vector3"], ts.types["geometry_msgs/msg/Quaternion"]
    return ts.types["sensor_msgs/msg/Imu"](
        header=_header(ts, t, ros1),
        orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.zeros(9),
        angular_velocity=V(x=0.001 * k, y=0.0, z=-0.5),
        angular_velocity_covariance=np.zeros(9),
        linear_acceleration=V(x=0.0, y=0.1 * k, z=9.8),
        linear_acceleration_covariance=np.zeros(9),
    )


def _pictures(k: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(k)
    return rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), rng.integers(
        0, 65536, (48, 64), dtype=np.uint16
    )


def _write_bag(path: Path, ros1: bool, *, second_imu: bool = False, infos: bool = True) -> None:
    """cam0: rgb8 raw images; cam1: PNG compressed (mono16 raw in ROS 1); IMU at 10x the frame
    rate, written a little before the header stamps (bag time != stamp)."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    ser = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    if ros1:
        from rosbags.rosbag1 import Writer as Ros1Writer

        writer: Any = Ros1Writer(path)
    else:
        from rosbags.rosbag2 import Writer as Ros2Writer

        writer = Ros2Writer(path, version=9)
    types = {
        "/cam0/image_raw": "sensor_msgs/msg/Image",
        "/imu0": "sensor_msgs/msg/Imu",
        "/cam1/image_raw": "sensor_msgs/msg/Image" if ros1 else "sensor_msgs/msg/CompressedImage",
    }
    if infos:
        types |= {
            "/cam0/camera_info": "sensor_msgs/msg/CameraInfo",
            "/cam1/camera_info": "sensor_msgs/msg/CameraInfo",
        }
    if second_imu:
        types["/imu_raw"] = "sensor_msgs/msg/Imu"
    with writer as w:
        conns = {t: w.add_connection(t, k, typestore=ts) for t, k in types.items()}

        def put(topic: str, bag_t: int, msg: Any) -> None:
            if topic in conns:
                w.write(conns[topic], bag_t, ser(msg, types[topic]))

        base = 1_700_000_000_000_000_000
        put("/cam0/camera_info", base, _info(ts, base, ros1, "plumb_bob", 0.0))
        put("/cam1/camera_info", base, _info(ts, base, ros1, "equidistant", -300.0 * 0.12))
        for k in range(40):
            t = base + k * 5_000_000
            put("/imu0", t + 700_000, _imu(ts, t, ros1, k))
            put("/imu_raw", t + 700_000, _imu(ts, t, ros1, -k))
            if k % 10 == 0:
                rgb, grey16 = _pictures(k)
                put("/cam0/image_raw", t + 1_000_000, _image(ts, t, ros1, "rgb8", rgb))
                if ros1:
                    msg = _image(ts, t, ros1, "mono16", grey16)
                else:
                    _, png = cv2.imencode(".png", rgb[:, :, ::-1].copy())
                    msg = ts.types["sensor_msgs/msg/CompressedImage"](
                        header=_header(ts, t, ros1), format="png", data=png.ravel()
                    )
                put("/cam1/image_raw", t + 2_000_000, msg)


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_bag_images_imu_and_camera_info(tmp_path: Path, ros1: bool) -> None:
    path = tmp_path / ("seq.bag" if ros1 else "seq")
    _write_bag(path, ros1)
    ds = open_dataset(path)
    assert ds.kind == "bag" and ds.rig.camera_names == ["cam0", "cam1"]
    c0, c1 = ds.rig.cameras
    assert c0.camera.model == "radtan" and c1.camera.model == "equidistant"
    np.testing.assert_array_equal(c0.camera.K, [[300, 0, 32.5], [0, 301, 24.5], [0, 0, 1]])
    assert c0.camera.dist.tolist() == [0.01, -0.002, 0.0003, -0.0004, 0.00005]
    assert ds.rig.baseline_m == pytest.approx(0.12, rel=1e-12)
    assert c0.rate_hz == 20.0 and ds.rig.imu is not None and ds.rig.imu.rate_hz == 200.0
    assert len(ds.frames) == 8 and len(ds.imu) == 40
    base = 1_700_000_000_000_000_000
    assert [f.t_ns for f in ds.frames_of("cam1")] == [base + k * 50_000_000 for k in range(4)]
    np.testing.assert_array_equal(ds.imu.accel_m_s2[3], [0.0, 0.30000000000000004, 9.8])
    items = list(ds.stream())
    assert [x.t_ns for x in items] == sorted(x.t_ns for x in items)
    assert isinstance(items[0], ImuSample) and isinstance(
        items[1], ImageFrame
    )  # equal stamps: IMU first
    rgb, grey16 = _pictures(20)
    f0, f1 = ds.frames_of("cam0")[2], ds.frames_of("cam1")[2]
    np.testing.assert_array_equal(f0.image(), rgb[:, :, ::-1])  # rgb8 -> BGR
    np.testing.assert_array_equal(
        f1.image(), (grey16 >> 8).astype(np.uint8) if ros1 else rgb[:, :, ::-1]
    )


def test_bag_topic_choice_and_calibration_file(tmp_path: Path) -> None:
    path = tmp_path / "two_imus"
    _write_bag(path, ros1=False, second_imu=True, infos=False)
    with pytest.raises(
        IoError, match=r"several IMU topics \(/imu0, /imu_raw\); choose one with imu_topic"
    ):
        open_dataset(path)
    with pytest.raises(
        IoError, match="no calibration for /cam0/image_raw: record /cam0/camera_info"
    ):
        open_dataset(path, imu_topic="/imu_raw")
    # a Kalibr camchain gives the calibration
    from tests.io.test_datasets_roundtrip import _rig

    rig = _rig("equidistant", stereo=True)
    write_camchain(tmp_path / "camchain.yaml", rig)
    ds = open_dataset(path, imu_topic="/imu_raw", calibration=tmp_path / "camchain.yaml")
    np.testing.assert_allclose(
        ds.rig.cameras[1].T_B_C.matrix(), rig.cameras[1].T_B_C.matrix(), atol=1e-15
    )
    assert ds.imu.gyro_rad_s[5, 0] == pytest.approx(-0.005)
    with pytest.raises(
        IoError, match=r"camchain.yaml: 2 cameras for 1 image topics \(/cam1/image_raw\)"
    ):
        open_dataset(
            path,
            imu_topic="/imu0",
            image_topics=("/cam1/image_raw",),
            calibration=tmp_path / "camchain.yaml",
        )
    with pytest.raises(
        IoError,
        match="image topic '/cam9' is not in the bag; its image topics: /cam0/image_raw, /cam1/image_raw",
    ):
        open_dataset(path, imu_topic="/imu0", image_topics=("/cam9",))


class _Msg:
    """A sensor_msgs Image or CompressedImage as decode_image sees it (fields only)."""

    def __init__(self, **fields: Any) -> None:
        self.__dict__.update(fields)


@pytest.mark.parametrize("enc", ["mono8", "mono16", "bgr8", "rgb8", "bgra8", "rgba8"])
def test_image_encodings(enc: str) -> None:
    from quadnav.io.datasets.bags import decode_image

    rng = np.random.default_rng(5)
    channels = {"mono8": 1, "mono16": 1, "bgr8": 3, "rgb8": 3, "bgra8": 4, "rgba8": 4}[enc]
    px = rng.integers(0, 65536 if enc == "mono16" else 256, (6, 5, channels)).squeeze()
    raw = px.astype("<u2").view(np.uint8) if enc == "mono16" else px.astype(np.uint8)
    pad = 3  # rows padded beyond width * channels, as step allows
    rows = np.hstack([raw.reshape(6, -1), np.zeros((6, pad), np.uint8)])
    msg = _Msg(
        height=6, width=5, step=rows.shape[1], encoding=enc, is_bigendian=0, data=rows.ravel()
    )
    out = decode_image(msg, "sensor_msgs/msg/Image")
    if enc == "mono16":
        expected = (px >> 8).astype(np.uint8)
    elif enc.startswith("rgb"):
        expected = px[:, :, [2, 1, 0]]
    else:
        expected = px[:, :, :3] if channels > 1 else px
    np.testing.assert_array_equal(out, expected)


def test_compressed_jpeg_and_bad_encodings() -> None:
    from quadnav.errors import SampleError
    from quadnav.io.datasets.bags import decode_image

    grey = np.tile(np.arange(0, 256, 4, dtype=np.uint8), (32, 1))
    _, jpg = cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, 95])
    out = decode_image(_Msg(format="jpeg", data=jpg.ravel()), "sensor_msgs/msg/CompressedImage")
    assert out.shape == (32, 64) and np.abs(out.astype(int) - grey).max() <= 4
    with pytest.raises(SampleError, match="cannot be decoded"):
        decode_image(
            _Msg(format="jpeg", data=np.zeros(10, np.uint8)), "sensor_msgs/msg/CompressedImage"
        )
    bayer = _Msg(
        height=2,
        width=2,
        step=2,
        encoding="bayer_rggb8",
        is_bigendian=0,
        data=np.zeros(4, np.uint8),
    )
    with pytest.raises(SampleError, match="encoding 'bayer_rggb8' is not one quadnav reads"):
        decode_image(bayer, "sensor_msgs/msg/Image")
    short = _Msg(
        height=4, width=4, step=4, encoding="mono8", is_bigendian=0, data=np.zeros(10, np.uint8)
    )
    with pytest.raises(SampleError, match="has 10 bytes, needs 16"):
        decode_image(short, "sensor_msgs/msg/Image")
