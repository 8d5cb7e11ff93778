"""The sample types that flow through quadnav.

Every sample is immutable and carries ``t_ns``, the time of validity of what it measures
(integer nanoseconds). A source may deliver it later than ``t_ns``; estimators handle that.
Shapes and finiteness are validated here, where data enters the library, so a NaN from a
sensor is a :class:`~quadnav.errors.SampleError` at the boundary, not a corrupted filter.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import SampleError
from quadnav.units import GNSS_ALT_RANGE_M

__all__ = [
    "FlowSample",
    "GpsSample",
    "HeightSample",
    "ImageFrame",
    "ImuSample",
    "MagSample",
    "Observation",
    "OdometrySample",
    "PoseSample",
    "PositionSample",
    "RangeSample",
    "RangeScan",
    "Sample",
    "StateEstimate",
    "TruthSample",
    "VehicleState",
    "VelocitySample",
    "check_t_ns",
]

FloatArray = NDArray[np.float64]


def check_t_ns(t_ns: Any, what: str) -> int:
    """Validate a timestamp: a plain integer number of nanoseconds (bool is refused)."""
    if isinstance(t_ns, bool) or not isinstance(t_ns, int | np.integer):
        raise SampleError(f"{what}.t_ns must be an integer number of nanoseconds, got {t_ns!r}")
    return int(t_ns)


def _array(value: Any, shape: tuple[int, ...], what: str) -> FloatArray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise SampleError(f"{what} is not numeric: {exc}") from None
    if arr.shape != shape:
        raise SampleError(f"{what} must have shape {shape}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise SampleError(f"{what} holds a non-finite value: {arr.ravel().tolist()}")
    arr.setflags(write=False)
    return arr


def slot_setters(cls: type, *names: str) -> tuple[Callable[[object, object], None], ...]:
    """The ``__set__`` of the named slots of a frozen ``slots`` dataclass: what a hot path's
    constructor (``object.__new__`` then these, no checks) calls, a third of the dataclass's
    own ``__init__``'s cost (which goes through ``object.__setattr__`` per field)."""
    return tuple(cls.__dict__[name].__set__ for name in names)


def _unit_quat(value: Any, what: str) -> FloatArray:
    q = _array(value, (4,), f"{what}.q_W_B_xyzw")
    n = float(np.linalg.norm(q))
    if abs(n - 1.0) > 1e-3:
        raise SampleError(f"{what}.q_W_B_xyzw must be a unit quaternion, got norm {n}")
    return q


def _spd(value: Any, shape: tuple[int, int], what: str) -> FloatArray:
    c = _array(value, shape, what)
    if not np.allclose(c, c.T, atol=1e-9 * max(1.0, float(np.abs(c).max()))):
        raise SampleError(f"{what} must be symmetric positive definite")
    if np.min(np.linalg.eigvalsh(c)) <= 0:
        raise SampleError(f"{what} must be symmetric positive definite")
    return c


@dataclass(frozen=True, slots=True, kw_only=True)
class ImuSample:
    """One IMU reading: body rate and specific force, both in the body frame (FLU)."""

    t_ns: int
    gyro_rad_s: FloatArray
    accel_m_s2: FloatArray

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", check_t_ns(self.t_ns, "ImuSample"))
        object.__setattr__(
            self, "gyro_rad_s", _array(self.gyro_rad_s, (3,), "ImuSample.gyro_rad_s")
        )
        object.__setattr__(
            self, "accel_m_s2", _array(self.accel_m_s2, (3,), "ImuSample.accel_m_s2")
        )

    @classmethod
    def from_checked(cls, t_ns: int, gyro: FloatArray, accel: FloatArray) -> ImuSample:
        """A sample from fresh finite float64 arrays of shape (3,) its maker has checked: the
        simulated IMU, hundreds of times a second, skips the checks (as
        :meth:`VehicleState.from_checked`)."""
        out = object.__new__(cls)
        set_t, set_gyro, set_accel = _IMU_SLOTS
        set_t(out, int(t_ns))
        gyro.setflags(write=False)
        accel.setflags(write=False)
        set_gyro(out, gyro)
        set_accel(out, accel)
        return out


@dataclass(frozen=True, slots=True, kw_only=True)
class ImageFrame:
    """One camera image at ``t_ns`` (the time stamp its source gives, in the IMU's clock once a
    camera-IMU offset is applied), from camera ``camera`` (``cam0``, ``cam1``...).

    The pixels load lazily: ``load`` is called by :meth:`image` each time, so a long sequence of
    frames holds file names, not images. ``exposure_s`` is the exposure time when the source
    gives it (0 when unknown); ``origin`` says where the pixels come from (a file, a bag topic)
    for error messages."""

    t_ns: int
    camera: str
    load: Callable[[], NDArray[np.uint8]] = field(repr=False)
    exposure_s: float = 0.0
    origin: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", check_t_ns(self.t_ns, "ImageFrame"))
        if not isinstance(self.camera, str) or not self.camera:
            raise SampleError(f"ImageFrame.camera must be a non-empty name, got {self.camera!r}")
        e = float(self.exposure_s)
        if not np.isfinite(e) or e < 0.0:
            raise SampleError(f"ImageFrame.exposure_s must be finite and >= 0, got {e}")
        object.__setattr__(self, "exposure_s", e)

    def image(self) -> NDArray[np.uint8]:
        """The pixels (h, w) grey or (h, w, 3), uint8; a :class:`SampleError` naming the frame's
        origin when they cannot be had (a missing or corrupt file)."""
        where = self.origin or f"{self.camera} at t_ns={self.t_ns}"
        try:
            img = self.load()
        except SampleError:
            raise
        except Exception as exc:  # a decoder's own error type: said in one line
            raise SampleError(f"image {where} cannot be read: {exc}") from None
        if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.ndim not in (2, 3):
            raise SampleError(f"image {where} cannot be read (not an 8-bit picture)")
        if (img.ndim == 3 and img.shape[2] not in (1, 3, 4)) or min(img.shape[:2]) == 0:
            raise SampleError(f"image {where} has an unusable shape {img.shape}")
        return img


@dataclass(frozen=True, slots=True, kw_only=True)
class PositionSample:
    """A position fix of the body origin in the world frame, ``p_W_B`` (ENU, metres).

    ``sigma_m`` is the standard deviation per axis the source claims; ``source`` names the
    sensor (``"gps"``, ``"vision"``...) so an estimator can keep a buffer per source.
    """

    t_ns: int
    p_W_B: FloatArray
    sigma_m: float
    source: str = "gps"

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", check_t_ns(self.t_ns, "PositionSample"))
        object.__setattr__(self, "p_W_B", _array(self.p_W_B, (3,), "PositionSample.p_W_B"))
        sigma = float(self.sigma_m)
        if not np.isfinite(sigma) or sigma <= 0.0:
            raise SampleError(f"PositionSample.sigma_m must be finite and > 0, got {self.sigma_m}")
        object.__setattr__(self, "sigma_m", sigma)


@dataclass(frozen=True, slots=True, kw_only=True)
class PoseSample:
    """An external pose of the body (vision: markers, VIO): ``p_W_B`` and ``q_W_B_xyzw`` with
    standard deviations for position (m, per axis) and heading (rad). ``reset_counter`` changes
    when the source re-initialises (a jump that must not be read as motion). ``cov_p_m2``, when
    given, is the full position covariance (3x3, m^2) and takes the place of ``sigma_pos_m``."""

    t_ns: int
    p_W_B: FloatArray
    q_W_B_xyzw: FloatArray
    sigma_pos_m: float
    sigma_yaw_rad: float
    reset_counter: int = 0
    source: str = "vision"
    cov_p_m2: FloatArray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", check_t_ns(self.t_ns, "PoseSample"))
        object.__setattr__(self, "p_W_B", _array(self.p_W_B, (3,), "PoseSample.p_W_B"))
        object.__setattr__(self, "q_W_B_xyzw", _unit_quat(self.q_W_B_xyzw, "PoseSample"))
        for name in ("sigma_pos_m", "sigma_yaw_rad"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v <= 0.0:
                raise SampleError(f"PoseSample.{name} must be finite and > 0, got {v}")
            object.__setattr__(self, name, v)
        if self.cov_p_m2 is not None:
            c = _spd(self.cov_p_m2, (3, 3), "PoseSample.cov_p_m2")
            object.__setattr__(self, "cov_p_m2", c)

    @classmethod
    def from_checked(
        cls, t_ns: int, p: FloatArray, q: FloatArray, sigma_pos_m: float, sigma_yaw_rad: float
    ) -> PoseSample:
        """A ``"vision"`` pose (no reset, no covariance) from fresh finite float64 arrays, a unit
        quaternion and positive sigmas its maker has checked: the simulated vision pose skips
        the checks (as :meth:`ImuSample.from_checked`), which cost more than the pose itself."""
        out = object.__new__(cls)
        p.setflags(write=False)
        q.setflags(write=False)
        values = (int(t_ns), p, q, float(sigma_pos_m), float(sigma_yaw_rad), 0, "vision", None)
        for set_, value in zip(_POSE_SLOTS, values, strict=True):
            set_(out, value)
        return out


@dataclass(frozen=True, slots=True, kw_only=True)
class VelocitySample:
    """A velocity of the body in the world (m/s) with its standard deviation per axis: a
    zero-velocity update while the vehicle is known to stand still (``source="landed"``)."""

    t_ns: int
    v_W_B: FloatArray
    sigma_m_s: float
    source: str = "landed"

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", check_t_ns(self.t_ns, "VelocitySample"))
        object.__setattr__(self, "v_W_B", _array(self.v_W_B, (3,), "VelocitySample.v_W_B"))
        v = float(self.sigma_m_s)
        if not np.isfinite(v) or v <= 0:
            raise SampleError(f"VelocitySample.sigma_m_s must be finite and > 0, got {v}")
        object.__setattr__(self, "sigma_m_s", v)


@dataclass(frozen=True, slots=True, kw_only=True)
class HeightSample:
    """A height of the body above the world origin (barometer, range finder), in metres."""

    t_ns: int
    z_m: float
    sigma_m: float
    source: str = "baro"

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", check_t_ns(self.t_ns, "HeightSample"))
        for name in ("z_m", "sigma_m"):
            v = float(getattr(self, name))
            if not np.isfinite(v):
                raise SampleError(f"HeightSample.{name} must be finite, got {v}")
            object.__setattr__(self, name, v)
        if self.sigma_m <= 0:
            raise SampleError(f"HeightSample.sigma_m must be > 0, got {self.sigma_m}")

    @classmethod
    def from_checked(cls, t_ns: int, z_m: float, sigma_m: float) -> HeightSample:
        """A ``"baro"`` height from a finite height and a positive sigma its maker has checked
        (the simulated barometer, as :meth:`ImuSample.from_checked`)."""
        out = object.__new__(cls)
        setattr_ = object.__setattr__
        setattr_(out, "t_ns", int(t_ns))
        setattr_(out, "z_m", float(z_m))
        setattr_(out, "sigma_m", float(sigma_m))
        setattr_(out, "source", "baro")
        return out


@dataclass(frozen=True, slots=True, kw_only=True)
class GpsSample:
    """A GNSS fix: geodetic latitude/longitude (degrees, WGS84), ellipsoidal altitude (m) and
    the velocity in the local ENU frame, with standard deviations."""

    t_ns: int
    lat_deg: float
    lon_deg: float
    alt_m: float
    v_enu_m_s: FloatArray
    sigma_h_m: float
    sigma_v_m: float
    sigma_vel_m_s: float
    source: str = "gps"

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", check_t_ns(self.t_ns, "GpsSample"))
        object.__setattr__(self, "v_enu_m_s", _array(self.v_enu_m_s, (3,), "GpsSample.v_enu_m_s"))
        for name in ("lat_deg", "lon_deg", "alt_m", "sigma_h_m", "sigma_v_m", "sigma_vel_m_s"):
            v = float(getattr(self, name))
            if not np.isfinite(v):
                raise SampleError(f"GpsSample.{name} must be finite, got {v}")
            object.__setattr__(self, name, v)
        if not (-90.0 <= self.lat_deg <= 90.0 and -180.0 <= self.lon_deg <= 180.0):
            raise SampleError(
                f"GpsSample: latitude/longitude out of range: {self.lat_deg}, {self.lon_deg}"
            )
        lo, hi = GNSS_ALT_RANGE_M
        if not lo <= self.alt_m <= hi:
            raise SampleError(f"GpsSample: altitude {self.alt_m} m outside [{lo:g}, {hi:g}] m")
        if min(self.sigma_h_m, self.sigma_v_m, self.sigma_vel_m_s) <= 0:
            raise SampleError("GpsSample standard deviations must be > 0")


@dataclass(frozen=True, slots=True, kw_only=True)
class MagSample:
    """A magnetometer reading: the magnetic field in the body frame (FLU), any unit."""

    t_ns: int
    field_B: FloatArray
    sigma_heading_rad: float
    source: str = "mag"

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", check_t_ns(self.t_ns, "MagSample"))
        f = _array(self.field_B, (3,), "MagSample.field_B")
        if float(np.linalg.norm(f)) == 0.0:
            raise SampleError("MagSample.field_B is zero")
        object.__setattr__(self, "field_B", f)
        v = float(self.sigma_heading_rad)
        if not np.isfinite(v) or v <= 0:
            raise SampleError(f"MagSample.sigma_heading_rad must be finite and > 0, got {v}")
        object.__setattr__(self, "sigma_heading_rad", v)


@dataclass(frozen=True, slots=True, kw_only=True)
class RangeSample:
    """A downward range finder: the distance along the body's -z axis to the ground (m).

    ``min_m``/``max_m`` is the sensor's valid span; a reading outside it is not a sample.
    """

    t_ns: int
    range_m: float
    sigma_m: float
    min_m: float = 0.05
    max_m: float = 10.0
    source: str = "range"

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", check_t_ns(self.t_ns, "RangeSample"))
        for name in ("range_m", "sigma_m", "min_m", "max_m"):
            v = float(getattr(self, name))
            if not np.isfinite(v):
                raise SampleError(f"RangeSample.{name} must be finite, got {v}")
            object.__setattr__(self, name, v)
        if self.sigma_m <= 0:
            raise SampleError(f"RangeSample.sigma_m must be > 0, got {self.sigma_m}")
        if not self.min_m <= self.range_m <= self.max_m:
            raise SampleError(
                f"RangeSample.range_m {self.range_m} outside the valid span "
                f"[{self.min_m}, {self.max_m}]"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class FlowSample:
    """A downward optical-flow sensor's integrated reading (PX4FLOW class, MAVLink
    ``OPTICAL_FLOW_RAD``), over an integration interval of ``integration_ns``.

    ``flow_rad`` is the optical flow integrated over the interval, as angles about the body
    x and y axes (FLU); ``gyro_rad`` the sensor's own gyro integrated over the same interval
    (about x, y, z). Signs as MAVLink and PX4's ``sensor_optical_flow``: a right-handed
    rotation of the sensor about an axis makes a positive flow about it, so in a pure
    rotation over still ground ``flow_rad == gyro_rad[:2]``; moving forward (+x) makes a
    negative flow about y, moving left (+y) a positive flow about x.

    ``t_ns`` is the time of validity: the **middle** of the integration interval (PX4's EKF2
    moves the sample's timestamp there as it turns the integrals into rates), so the
    interval is ``[t_ns - integration_ns / 2, t_ns + integration_ns / 2]``.

    ``quality`` is the sensor's 0-255 (0: no valid flow, 255: best); ``distance_m`` the
    reading of its range sensor to the centre of the flow field (m), ``None`` when unknown
    (MAVLink's negative distance).
    """

    t_ns: int
    integration_ns: int
    flow_rad: FloatArray
    gyro_rad: FloatArray
    quality: int
    distance_m: float | None = None
    source: str = "flow"

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", check_t_ns(self.t_ns, "FlowSample"))
        n = self.integration_ns
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n <= 0:
            raise SampleError(
                f"FlowSample.integration_ns must be an integer number of ns > 0, got {n!r}"
            )
        object.__setattr__(self, "integration_ns", int(n))
        object.__setattr__(self, "flow_rad", _array(self.flow_rad, (2,), "FlowSample.flow_rad"))
        object.__setattr__(self, "gyro_rad", _array(self.gyro_rad, (3,), "FlowSample.gyro_rad"))
        q = self.quality
        if isinstance(q, bool) or not isinstance(q, int | np.integer) or not 0 <= q <= 255:
            raise SampleError(f"FlowSample.quality must be an integer in 0..255, got {q!r}")
        object.__setattr__(self, "quality", int(q))
        if self.distance_m is not None:
            d = float(self.distance_m)
            if not np.isfinite(d) or d < 0:
                raise SampleError(f"FlowSample.distance_m must be finite and >= 0, got {d}")
            object.__setattr__(self, "distance_m", d)

    @property
    def dt_s(self) -> float:
        """The integration interval in seconds."""
        return self.integration_ns * 1e-9

    @property
    def flow_rate_rad_s(self) -> FloatArray:
        """The mean flow rate over the interval (rad/s, about body x and y)."""
        return np.asarray(self.flow_rad / self.dt_s, dtype=np.float64)

    @property
    def gyro_rate_rad_s(self) -> FloatArray:
        """The sensor gyro's mean rate over the interval (rad/s, body x, y, z)."""
        return np.asarray(self.gyro_rad / self.dt_s, dtype=np.float64)


@dataclass(frozen=True, slots=True, kw_only=True)
class RangeScan:
    """A planar laser scan in the body frame: ray ``i`` points at ``angle_min_rad + i *
    angle_increment_rad`` from body +x (counter-clockwise, about body +z); ``ranges_m`` holds
    ``inf`` where nothing was hit within ``range_max_m`` (as sensor_msgs/LaserScan).
    """

    t_ns: int
    angle_min_rad: float
    angle_increment_rad: float
    range_max_m: float
    ranges_m: FloatArray

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", check_t_ns(self.t_ns, "RangeScan"))
        r = np.array(self.ranges_m, dtype=np.float64)
        if r.ndim != 1 or len(r) == 0 or np.isnan(r).any() or (r < 0).any():
            raise SampleError(
                "RangeScan.ranges_m must be a non-empty 1-D array of ranges >= 0 (inf: no hit)"
            )
        r.setflags(write=False)
        object.__setattr__(self, "ranges_m", r)

    @property
    def angles_rad(self) -> FloatArray:
        return np.asarray(
            self.angle_min_rad + self.angle_increment_rad * np.arange(len(self.ranges_m)),
            dtype=np.float64,
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class OdometrySample:
    """External odometry of the body, as PX4's ``ODOMETRY`` message carries it from a companion
    computer (VIO): the pose ``p_W_B``, ``q_W_B_xyzw`` and the velocity ``v_W_B`` (world frame)
    in the source's own gravity-aligned frame ``W``, with covariances. ``cov_pose`` is 6x6 over
    (x, y, z, rx, ry, rz): position in m^2, then the attitude error as a small rotation in the
    world frame (``R_true = Exp(dtheta) R_est``) in rad^2, PX4's order. ``cov_v`` is 3x3 (m/s)^2
    in the world frame. ``reset_counter`` changes when the source re-initialises (its frame
    jumps); ``quality`` is 0-100 (PX4: 0 invalid, 100 best)."""

    t_ns: int
    p_W_B: FloatArray
    q_W_B_xyzw: FloatArray
    v_W_B: FloatArray
    cov_pose: FloatArray
    cov_v: FloatArray
    reset_counter: int = 0
    quality: int = 100
    source: str = "vio"

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", check_t_ns(self.t_ns, "OdometrySample"))
        object.__setattr__(self, "p_W_B", _array(self.p_W_B, (3,), "OdometrySample.p_W_B"))
        object.__setattr__(self, "v_W_B", _array(self.v_W_B, (3,), "OdometrySample.v_W_B"))
        object.__setattr__(self, "q_W_B_xyzw", _unit_quat(self.q_W_B_xyzw, "OdometrySample"))
        for name, shape in (("cov_pose", (6, 6)), ("cov_v", (3, 3))):
            object.__setattr__(
                self, name, _spd(getattr(self, name), shape, f"OdometrySample.{name}")
            )
        if not 0 <= int(self.quality) <= 100:
            raise SampleError(f"OdometrySample.quality must be 0-100, got {self.quality}")


Observation = (
    PositionSample
    | PoseSample
    | OdometrySample
    | HeightSample
    | GpsSample
    | MagSample
    | RangeSample
    | VelocitySample
    | FlowSample
)


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleState:
    """The true state of a simulated vehicle (what sensors sample from).

    ``a_W_B`` is the kinematic acceleration of the body origin in the world frame;
    ``w_B`` the angular velocity of the body, expressed in the body frame.
    """

    t_ns: int
    p_W_B: FloatArray
    v_W_B: FloatArray
    a_W_B: FloatArray
    q_W_B_xyzw: FloatArray
    w_B: FloatArray

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", check_t_ns(self.t_ns, "VehicleState"))
        for name in ("p_W_B", "v_W_B", "a_W_B", "w_B"):
            object.__setattr__(
                self, name, _array(getattr(self, name), (3,), f"VehicleState.{name}")
            )
        q = _array(self.q_W_B_xyzw, (4,), "VehicleState.q_W_B_xyzw")
        if abs(float(np.linalg.norm(q)) - 1.0) > 1e-6:
            raise SampleError(
                f"VehicleState.q_W_B_xyzw must be a unit quaternion, got {q.tolist()}"
            )
        object.__setattr__(self, "q_W_B_xyzw", q)

    @classmethod
    def from_checked(
        cls, t_ns: int, p: FloatArray, v: FloatArray, a: FloatArray, q: FloatArray, w: FloatArray
    ) -> VehicleState:
        """A state from fresh float64 arrays its maker has checked (finite, the shapes, a unit
        quaternion): the simulator's integrator, 1,000 times a second, skips the checks."""
        out = object.__new__(cls)
        object.__setattr__(out, "t_ns", int(t_ns))
        for name, arr in (("p_W_B", p), ("v_W_B", v), ("a_W_B", a), ("q_W_B_xyzw", q), ("w_B", w)):
            arr.setflags(write=False)
            object.__setattr__(out, name, arr)
        return out

    @classmethod
    def from_vector(cls, t_ns: int, s: FloatArray, a: FloatArray) -> VehicleState:
        """:meth:`from_checked` of one fresh float64 array ``s`` (its first 13: position,
        velocity, quaternion, body rate) and the acceleration ``a`` (3): made read-only once,
        the fields are views of ``s`` (the simulator's state, a thousand times a second)."""
        s.setflags(write=False)
        a.setflags(write=False)
        out = object.__new__(cls)
        set_t, set_p, set_v, set_a, set_q, set_w = _VEHICLE_SLOTS
        set_t(out, int(t_ns))
        set_p(out, s[0:3])
        set_v(out, s[3:6])
        set_a(out, a)
        set_q(out, s[6:10])
        set_w(out, s[10:13])
        return out


@dataclass(frozen=True, slots=True, kw_only=True)
class TruthSample:
    """The simulator's true state as a perfect sensor reports it (it feeds the truth estimator,
    ``estimator.kind=truth``; a filter counts it as unsupported)."""

    t_ns: int
    state: VehicleState
    source: str = "truth"

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_ns", check_t_ns(self.t_ns, "TruthSample"))


Sample = ImuSample | Observation | TruthSample

_IMU_SLOTS = slot_setters(ImuSample, "t_ns", "gyro_rad_s", "accel_m_s2")
_POSE_SLOTS = slot_setters(
    PoseSample, "t_ns", "p_W_B", "q_W_B_xyzw", "sigma_pos_m", "sigma_yaw_rad", "reset_counter",
    "source", "cov_p_m2",
)  # fmt: skip
_VEHICLE_SLOTS = slot_setters(VehicleState, "t_ns", "p_W_B", "v_W_B", "a_W_B", "q_W_B_xyzw", "w_B")


@dataclass(frozen=True, slots=True, kw_only=True)
class StateEstimate:
    """An estimator's state at one time horizon.

    ``x`` is the estimator's own state vector with ``names`` naming its entries, and ``P``
    its covariance (``None`` where the horizon carries none, as the output predictor).
    ``p_W_B``, ``v_W_B`` and ``q_W_B_xyzw`` give the same state in the common 3-D form.
    """

    t_ns: int
    p_W_B: FloatArray
    v_W_B: FloatArray
    q_W_B_xyzw: FloatArray
    x: FloatArray
    names: tuple[str, ...]
    P: FloatArray | None = field(default=None)
    #: The body's angular rate (rad/s, body frame, gyro bias removed), where the estimator has one.
    w_B: FloatArray | None = field(default=None)

    @classmethod
    def from_checked(
        cls, t_ns: int, p: FloatArray, v: FloatArray, q: FloatArray, x: FloatArray,
        names: tuple[str, ...], P: FloatArray | None, w_B: FloatArray | None,
    ) -> StateEstimate:  # fmt: skip
        """An estimate from arrays its maker owns and has checked (an output predictor's,
        hundreds of times a second), without the dataclass's ``__init__``."""
        out = object.__new__(cls)
        set_t, set_p, set_v, set_q, set_x, set_names, set_P, set_w = _ESTIMATE_SLOTS
        set_t(out, t_ns)
        set_p(out, p)
        set_v(out, v)
        set_q(out, q)
        set_x(out, x)
        set_names(out, names)
        set_P(out, P)
        set_w(out, w_B)
        return out


_ESTIMATE_SLOTS = slot_setters(
    StateEstimate, "t_ns", "p_W_B", "v_W_B", "q_W_B_xyzw", "x", "names", "P", "w_B"
)
