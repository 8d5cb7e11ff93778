"""Camera-IMU rigs: the cameras (intrinsics, distortion, ``T_B_C``, rate, time offset), the IMU
(rate, noise densities) and an optional depth sensor, shared by the simulator (what to render
and synthesize), the dataset readers and writers (what a ``sensor.yaml`` says) and the visual
estimators (what they calibrate with).

``B`` is the rig's body frame: FLU for quadnav's own rigs, the IMU frame for a dataset's
(EuRoC's ``T_BS`` of ``imu0`` is the identity). ``C`` is OpenCV's camera frame (x right, y down,
z forward). A camera's ``time_offset_ns`` is VINS-Mono's ``td``: a frame stamped ``t_cam`` was
taken at IMU time ``t_cam + time_offset_ns``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.random import Generator
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import GeometryError
from quadnav.geometry.camera import PinholeCamera, thesis_camera
from quadnav.geometry.multiview import nearest_rotation
from quadnav.geometry.rotations import Pose
from quadnav.units import GRAVITY_M_S2

__all__ = [
    "RIGS",
    "CameraSpec",
    "DepthSpec",
    "ImuNoiseModel",
    "ImuSpec",
    "Rig",
    "rig_named",
]

FloatArray = NDArray[np.float64]
Vec3 = tuple[float, float, float]

# A forward-looking camera on an FLU body: image x right = -y_B, image y down = -z_B, optical
# axis = x_B. A downward one (thesis 000's mount): optical axis -z_B, image x towards the tail.
R_B_C_FORWARD = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
R_B_C_DOWN_THESIS000 = np.array([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])


def _positive(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v) or v <= 0.0:
        raise GeometryError(f"{name} must be finite and > 0, got {value}")
    return v


@dataclass(frozen=True, slots=True, kw_only=True)
class ImuNoiseModel:
    """Continuous-time IMU noise, in the names of EuRoC's and Kalibr's ``imu0`` YAML: white-noise
    densities (``gyro`` rad/s/sqrt(Hz), ``accel`` m/s^2/sqrt(Hz)) and bias random walks (rad/s^2/
    sqrt(Hz), m/s^3/sqrt(Hz)), with the biases at the start. A sample at rate ``f`` has white
    noise of standard deviation ``density * sqrt(f)``. ``*_bias0_sigma_*`` is the spread of the
    turn-on bias over power-ups (1 sigma per axis; what a datasheet calls the initial bias error
    or bias repeatability): a synthetic IMU draws its ``*_bias0_*`` from it
    (:meth:`draw_turn_on_biases`)."""

    gyro_noise_density: float
    gyro_random_walk: float
    accel_noise_density: float
    accel_random_walk: float
    gyro_bias0_rad_s: Vec3 = (0.0, 0.0, 0.0)
    accel_bias0_m_s2: Vec3 = (0.0, 0.0, 0.0)
    gyro_bias0_sigma_rad_s: float = 0.0
    accel_bias0_sigma_m_s2: float = 0.0

    def __post_init__(self) -> None:
        for name in (
            "gyro_noise_density",
            "gyro_random_walk",
            "accel_noise_density",
            "accel_random_walk",
            "gyro_bias0_sigma_rad_s",
            "accel_bias0_sigma_m_s2",
        ):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v < 0.0:
                raise GeometryError(f"IMU {name} must be finite and >= 0, got {v}")
            object.__setattr__(self, name, v)
        for name in ("gyro_bias0_rad_s", "accel_bias0_m_s2"):
            b = tuple(float(x) for x in getattr(self, name))
            if len(b) != 3 or not all(math.isfinite(x) for x in b):
                raise GeometryError(f"IMU {name} must be 3 finite numbers, got {b}")
            object.__setattr__(self, name, b)

    @classmethod
    def euroc_adis16448(cls) -> ImuNoiseModel:
        """EuRoC's ADIS16448: the densities of its ``imu0/sensor.yaml`` (the datasheet's: angular
        random walk 0.66 deg/sqrt(h) = 1.9e-4 rad/s/sqrt(Hz), velocity random walk
        0.11 m/s/sqrt(h) = 1.8e-3 m/s^2/sqrt(Hz)). Turn-on biases of 0.5 deg/s and 20 mg (1 sigma):
        the ADIS16448 defaults of ETH ASL's RotorS simulator (``gazebo_imu_plugin.h``,
        ``kDefaultAdis*TurnOnBiasSigma``), the lab that recorded EuRoC. (EuRoC's own V1_01 biases,
        as OpenVINS estimates them, are bg (-0.002, 0.021, 0.077) rad/s and ba up to 0.19 m/s^2:
        the gyro's z beyond that spread, the accelerometer's within it.)"""
        return cls(
            gyro_noise_density=1.6968e-04,
            gyro_random_walk=1.9393e-05,
            accel_noise_density=2.0000e-3,
            accel_random_walk=3.0000e-3,
            gyro_bias0_sigma_rad_s=math.radians(0.5),
            accel_bias0_sigma_m_s2=20.0e-3 * GRAVITY_M_S2,
        )

    @classmethod
    def euroc_adis16448_in_flight(cls) -> ImuNoiseModel:
        """The white noise EuRoC's ADIS16448 shows in flight on its MAV (rotor vibration
        included), measured in ``euroc_micro`` (V1_01_easy's IMU, 200 Hz): from 10 s to 140 s,
        each axis less its centred 0.1 s moving average, the per-sample standard deviation over
        sqrt(200 Hz), the RMS over the axes: gyro 2.8e-3 rad/s/sqrt(Hz) (axes 1.5, 3.7,
        2.7e-3; 16x the datasheet's 1.7e-4), accelerometer 0.062 m/s^2/sqrt(Hz) (axes 0.080,
        0.037, 0.061; 31x its 2.0e-3). VINS-Mono's EuRoC configuration inflates to the same
        order (gyr_n 0.004, acc_n 0.08). Standing on the ground before take-off the same IMU
        shows 1.3e-3 and 0.024 (0 to 4.7 s), 3.4e-4 and 6e-3 in its quietest half second. The
        random walks (not measurable in 145 s) and the turn-on spread are the datasheet's."""
        return replace(cls.euroc_adis16448(), gyro_noise_density=2.8e-3, accel_noise_density=0.062)

    @classmethod
    def euroc_adis16448_on_ground(cls) -> ImuNoiseModel:
        """The white noise of EuRoC's ADIS16448 on the ground before take-off, measured as
        :meth:`euroc_adis16448_in_flight` over V1_01's steadiest stretch, 1.5 to 3.5 s (the
        vehicle moves 1.7 cm in its first 4.7 s): gyro 8.4e-4 rad/s/sqrt(Hz) (axes 0.91, 0.90,
        0.69e-3), accelerometer 0.014 m/s^2/sqrt(Hz) (axes 0.016, 0.015, 0.009); over all of
        0 to 4.7 s, with a disturbance first and the take-off last, 2.2e-3 and 0.032."""
        return replace(cls.euroc_adis16448(), gyro_noise_density=8.4e-4, accel_noise_density=0.014)

    def draw_turn_on_biases(self, rng: Generator, scale: float = 1.0) -> ImuNoiseModel:
        """This model with turn-on biases drawn per axis from a normal of ``scale`` times its
        ``*_bias0_sigma_*``, clipped to 3 sigma (the range a datasheet's 1 sigma implies)."""
        g = np.clip(rng.standard_normal(3), -3.0, 3.0) * self.gyro_bias0_sigma_rad_s * scale
        a = np.clip(rng.standard_normal(3), -3.0, 3.0) * self.accel_bias0_sigma_m_s2 * scale
        return replace(
            self,
            gyro_bias0_rad_s=(float(g[0]), float(g[1]), float(g[2])),
            accel_bias0_m_s2=(float(a[0]), float(a[1]), float(a[2])),
        )

    def sensor_yaml(self) -> dict[str, float]:
        """The four densities by the keys of EuRoC's and Kalibr's ``imu0/sensor.yaml``."""
        return {
            "gyroscope_noise_density": self.gyro_noise_density,
            "gyroscope_random_walk": self.gyro_random_walk,
            "accelerometer_noise_density": self.accel_noise_density,
            "accelerometer_random_walk": self.accel_random_walk,
        }

    def without_noise(self) -> ImuNoiseModel:
        return ImuNoiseModel(
            gyro_noise_density=0.0,
            gyro_random_walk=0.0,
            accel_noise_density=0.0,
            accel_random_walk=0.0,
            gyro_bias0_rad_s=self.gyro_bias0_rad_s,
            accel_bias0_m_s2=self.accel_bias0_m_s2,
            gyro_bias0_sigma_rad_s=self.gyro_bias0_sigma_rad_s,
            accel_bias0_sigma_m_s2=self.accel_bias0_sigma_m_s2,
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class ImuSpec:
    """An IMU at ``rate_hz`` with its noise, mounted at ``T_B_I`` (the identity when the body frame
    is the IMU's, as in EuRoC). ``noise`` is what its calibration file states (a datasheet's);
    ``flight_noise`` what it shows on the vehicle in flight (vibration included), which realistic
    synthetic data is made with (None: the stated one), and ``ground_noise`` what it shows
    standing on the ground before take-off (None: the in-flight level throughout)."""

    rate_hz: float
    noise: ImuNoiseModel
    T_B_I: Pose = field(default_factory=Pose.identity)
    name: str = "imu0"
    flight_noise: ImuNoiseModel | None = None
    ground_noise: ImuNoiseModel | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "rate_hz", _positive("IMU rate_hz", self.rate_hz))


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraSpec:
    """A camera of a rig: its lens, its pose in the body ``T_B_C``, its frame rate, its time offset
    to the IMU (``t_imu = t_cam + time_offset_ns``) and its exposure time (for motion blur)."""

    name: str
    camera: PinholeCamera
    T_B_C: Pose
    rate_hz: float
    time_offset_ns: int = 0
    exposure_s: float = 0.0

    def __post_init__(self) -> None:
        if not self.name:
            raise GeometryError("a camera of a rig needs a name (cam0, cam1...)")
        object.__setattr__(self, "rate_hz", _positive(f"{self.name} rate_hz", self.rate_hz))
        e = float(self.exposure_s)
        if not math.isfinite(e) or e < 0.0 or e > 1.0 / self.rate_hz:
            raise GeometryError(
                f"{self.name} exposure_s must be in [0, 1/rate_hz = {1.0 / self.rate_hz:g}], got {e}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class DepthSpec:
    """An RGB-D depth image registered to camera ``camera``: noise of standard deviation
    ``sigma0_m + sigma_per_m2 * z**2`` (structured light and active stereo grow with the square of
    the distance), no reading outside ``[min_range_m, max_range_m]``."""

    camera: str = "cam0"
    sigma0_m: float = 0.001
    sigma_per_m2: float = 0.0025
    min_range_m: float = 0.2
    max_range_m: float = 8.0

    def __post_init__(self) -> None:
        if not (0.0 <= self.sigma0_m < 1.0 and 0.0 <= self.sigma_per_m2 < 1.0):
            raise GeometryError(
                f"depth noise must be in [0, 1): sigma0_m={self.sigma0_m}, "
                f"sigma_per_m2={self.sigma_per_m2}"
            )
        if not (0.0 <= self.min_range_m < self.max_range_m <= 1e3):
            raise GeometryError(
                f"depth range must satisfy 0 <= min_range_m < max_range_m <= 1000, got "
                f"{self.min_range_m}..{self.max_range_m}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class Rig:
    """Cameras (``cam0`` first), the IMU (``None`` for a camera-only dataset such as KITTI's
    odometry images) and an optional depth sensor. ``T_V_B`` is the rig's body frame on a
    vehicle's FLU frame, for motions of a vehicle (a simulated flight): the identity when the
    body is FLU, EuRoC's VI-Sensor mount for its IMU frame (x up, y right, z forward)."""

    name: str
    cameras: tuple[CameraSpec, ...]
    imu: ImuSpec | None
    depth: DepthSpec | None = None
    T_V_B: Pose = field(default_factory=Pose.identity)

    def __post_init__(self) -> None:
        if not self.cameras:
            raise GeometryError(f"rig {self.name!r} has no camera")
        names = [c.name for c in self.cameras]
        if len(set(names)) != len(names):
            raise GeometryError(f"rig {self.name!r} names a camera twice: {names}")
        if self.depth is not None and self.depth.camera not in names:
            raise GeometryError(
                f"rig {self.name!r}: depth registered to {self.depth.camera!r}, not one of {names}"
            )

    def camera(self, name: str) -> CameraSpec:
        for c in self.cameras:
            if c.name == name:
                return c
        raise GeometryError(f"rig {self.name!r} has no camera {name!r}: {self.camera_names}")

    @property
    def camera_names(self) -> list[str]:
        return [c.name for c in self.cameras]

    @property
    def stereo(self) -> bool:
        return len(self.cameras) >= 2

    @property
    def baseline_m(self) -> float:
        """The distance between the first two cameras' centres (0 for a mono rig)."""
        if not self.stereo:
            return 0.0
        return float(np.linalg.norm(self.cameras[1].T_B_C.p_A_B - self.cameras[0].T_B_C.p_A_B))


def _pinhole(
    fx: float, fy: float, cx: float, cy: float, w: int, h: int, dist: list[float]
) -> PinholeCamera:
    return PinholeCamera(
        np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), np.array(dist), w, h
    )


def _pose(R: FloatArray, p: Vec3) -> Pose:
    return Pose(Rotation.from_matrix(R), np.asarray(p, dtype=np.float64))


# A small multirotor's IMU (MPU-6000 class, as in a Pixhawk; the order of PX4's defaults).
# Its turn-on biases: PX4's EKF2 switch-on bias 1 sigma (EKF2_GBIAS_INIT 0.1 rad/s; accelerometer
# 0.2 m/s^2, EKF2_ABIAS_INIT), what is left after the flight controller's own calibration (the
# MPU-6000's raw initial tolerance, +-20 deg/s and +-50 mg, is calibrated out at boot).
_FC_IMU = ImuNoiseModel(
    gyro_noise_density=2.4e-4,
    gyro_random_walk=2.0e-5,
    accel_noise_density=2.8e-3,
    accel_random_walk=4.0e-4,
    gyro_bias0_sigma_rad_s=0.1,
    accel_bias0_sigma_m_s2=0.2,
)
# In flight: no measurement of our own; the vibration is the vehicle's, so EuRoC's MAV's level
# (ImuNoiseModel.euroc_adis16448_in_flight), with this IMU's random walks.
_FC_IMU_FLIGHT = replace(_FC_IMU, gyro_noise_density=2.8e-3, accel_noise_density=0.062)
_FC_IMU_GROUND = replace(_FC_IMU, gyro_noise_density=8.4e-4, accel_noise_density=0.014)


def _fc_imu(rate_hz: float) -> ImuSpec:
    return ImuSpec(
        rate_hz=rate_hz, noise=_FC_IMU, flight_noise=_FC_IMU_FLIGHT, ground_noise=_FC_IMU_GROUND
    )


def thesis003_sim() -> Rig:
    """Thesis 003's simulated camera (its VINS-Mono YAML: 640x480, fx = fy = 381.3625, cx 320.5,
    cy 240.5, no distortion, 20 Hz) looking forward, 10 cm ahead of the centre, IMU at 200 Hz."""
    cam = _pinhole(381.3625, 381.3625, 320.5, 240.5, 640, 480, [])
    spec = CameraSpec(
        name="cam0", camera=cam, T_B_C=_pose(R_B_C_FORWARD, (0.1, 0.0, 0.0)), rate_hz=20.0
    )
    return Rig(name="thesis003_sim", cameras=(spec,), imu=_fc_imu(200.0))


# EuRoC's cam0/cam1 (its sensor.yaml): T_BS rows, intrinsics fu fv cu cv, radial-tangential.
_EUROC_T_BS = {
    "cam0": [
        [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
        [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
        [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
        [0.0, 0.0, 0.0, 1.0],
    ],
    "cam1": [
        [0.0125552670891, -0.999755099723, 0.0182237714554, -0.0198435579556],
        [0.999598781151, 0.0130119051815, 0.0251588363115, 0.0453689425024],
        [-0.0253898008918, 0.0179005838253, 0.999517347078, 0.00786212447038],
        [0.0, 0.0, 0.0, 1.0],
    ],
}
_EUROC_CAMERAS = {
    "cam0": (
        (458.654, 457.296, 367.215, 248.375),
        [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
    ),
    "cam1": (
        (457.587, 456.134, 379.999, 255.238),
        [-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05],
    ),
}


def _orthonormal(T: list[list[float]]) -> Pose:
    """A calibration's 4x4 with its rotation block made exactly orthonormal (SVD)."""
    M = np.asarray(T, dtype=np.float64)
    return Pose(Rotation.from_matrix(nearest_rotation(M[:3, :3])), M[:3, 3])


def _euroc_mount(pitch_down_deg: float = 20.0) -> Pose:
    """The VI-Sensor on a vehicle (FLU): its IMU's x up, y right, z forward, pitched down (EuRoC's
    IMU reads gravity about 22 degrees off its x axis, towards -z, on the ground), 10 cm ahead."""
    th = math.radians(pitch_down_deg)
    x_I = [math.sin(th), 0.0, math.cos(th)]
    y_I = [0.0, -1.0, 0.0]
    z_I = [math.cos(th), 0.0, -math.sin(th)]
    return _pose(np.column_stack([x_I, y_I, z_I]), (0.1, 0.0, -0.03))


def euroc() -> Rig:
    """EuRoC's VI-Sensor: two MT9M034 cameras (752x480, 20 Hz, 110 mm apart) and the ADIS16448 at
    200 Hz, with the calibration of its ``sensor.yaml`` files; the body frame is the IMU's, mounted
    on a vehicle looking forward, 20 degrees down."""
    cams = []
    for name in ("cam0", "cam1"):
        (fu, fv, cu, cv), dist = _EUROC_CAMERAS[name]
        cams.append(
            CameraSpec(
                name=name,
                camera=_pinhole(fu, fv, cu, cv, 752, 480, dist),
                T_B_C=_orthonormal(_EUROC_T_BS[name]),
                rate_hz=20.0,
            )
        )
    return Rig(
        name="euroc",
        cameras=tuple(cams),
        imu=ImuSpec(
            rate_hz=200.0,
            noise=ImuNoiseModel.euroc_adis16448(),
            flight_noise=ImuNoiseModel.euroc_adis16448_in_flight(),
            ground_noise=ImuNoiseModel.euroc_adis16448_on_ground(),
        ),
        T_V_B=_euroc_mount(),
    )


def euroc_mono() -> Rig:
    """EuRoC's VI-Sensor with its left camera only (cam0 and the ADIS16448): the monocular
    visual-inertial rig of VINS-Mono's EuRoC runs, half the images to render and store."""
    full = euroc()
    return Rig(name="euroc_mono", cameras=full.cameras[:1], imu=full.imu, T_V_B=full.T_V_B)


def zed() -> Rig:
    """Thesis 002's ZED in WVGA (672x376 per eye, 60 Hz, 120 mm baseline), rectified (no
    distortion), looking forward; typical factory intrinsics of that mode (fx = fy = 350 px). The
    ZED has no IMU of its own: the flight controller's, at 200 Hz."""
    cam = _pinhole(350.0, 350.0, 336.0, 188.0, 672, 376, [])
    left = CameraSpec(
        name="cam0", camera=cam, T_B_C=_pose(R_B_C_FORWARD, (0.1, 0.06, 0.0)), rate_hz=60.0
    )
    right = CameraSpec(
        name="cam1", camera=cam, T_B_C=_pose(R_B_C_FORWARD, (0.1, -0.06, 0.0)), rate_hz=60.0
    )
    return Rig(name="zed", cameras=(left, right), imu=_fc_imu(200.0))


def pi_camera() -> Rig:
    """Thesis 000's Raspberry Pi Camera v2 (its ``cal.yml``, 640x480, 40 fps as its video), looking
    down, turned 180 degrees about the vertical (the thesis mount)."""
    spec = CameraSpec(
        name="cam0",
        camera=thesis_camera(),
        T_B_C=_pose(R_B_C_DOWN_THESIS000, (0.0, 0.0, -0.05)),
        rate_hz=40.0,
    )
    return Rig(name="pi_camera", cameras=(spec,), imu=_fc_imu(250.0))


def rgbd() -> Rig:
    """Thesis 003's camera with a registered depth image (an RGB-D camera of the RealSense D435
    class: 1 mm + 2.5 mm/m^2 z^2, 0.2-8 m), 20 Hz, IMU at 200 Hz."""
    base = thesis003_sim()
    return Rig(name="rgbd", cameras=base.cameras, imu=base.imu, depth=DepthSpec())


RIGS: Mapping[str, Callable[[], Rig]] = {
    "thesis003_sim": thesis003_sim,
    "euroc": euroc,
    "euroc_mono": euroc_mono,
    "zed": zed,
    "pi_camera": pi_camera,
    "rgbd": rgbd,
}


def rig_named(name: str) -> Rig:
    """A built-in rig by name; a one-line error listing them for another name."""
    try:
        return RIGS[name]()
    except KeyError:
        raise GeometryError(f"unknown rig {name!r}; built in: {', '.join(RIGS)}") from None
