"""GNSS fixes in a robot's world frame and back: robot_localization's ``navsat_transform``,
on a local tangent plane (pymap3d's ENU about a datum) rather than UTM, so that no zone or
hemisphere changes under the robot.

Three frames: geodetic (WGS84 latitude, longitude, ellipsoidal altitude), ``E`` the east-north-up
plane tangent at the datum, and ``W`` the robot's world frame (an odometry's, gravity-aligned,
its own origin and heading). ``W`` is ``E`` turned by ``yaw_W_E`` about the vertical and moved by
``p_W_E``; :meth:`NavSatTransform.from_first_fix` finds both from one fix and what the robot
knew at that moment: its pose in ``W`` and its heading from an IMU or compass.

Headings (radians, counter-clockwise from above):

- ENU heading ``yaw_E`` is zero facing east, pi/2 facing north (REP-103).
- An IMU's or compass's heading ``yaw_imu`` becomes ``yaw_E = yaw_imu + yaw_offset - declination``.
  ``yaw_offset_rad`` is the IMU's own convention: 0 for an IMU whose zero faces east
  (REP-103), pi/2 for one that reads zero facing north (the case robot_localization's users
  trip on). ``magnetic_declination_rad`` is the place's declination, **east positive** as
  NOAA's calculator gives it (magnetic north that many radians clockwise of true north), for a
  heading measured from magnetic north: with 10 degrees east, a vehicle facing magnetic north
  reads 90 degrees and faces 80 degrees in ENU. Give 0 for an IMU that reports true heading.
  (The navigation EKF's magnetometer uses the same sign: magnetic north at ``pi/2 - D``.)

A GNSS antenna ``lever_arm_B_m`` off the body's origin (body FLU) is taken out with the body's
attitude, so that a robot turning in place keeps its position (raw fixes of an antenna 0.5 m
ahead draw a circle 1 m across). ``zero_altitude`` puts every fix at the world origin's height
(robot_localization's ``zero_altitude``, for ground robots).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quadnav.errors import GeometryError
from quadnav.geometry.rotations import rot_z
from quadnav.units import GNSS_ALT_RANGE_M

__all__ = ["GeoDatum", "NavSatTransform", "enu_heading"]

FloatArray = NDArray[np.float64]

MIN_ALT_M, MAX_ALT_M = GNSS_ALT_RANGE_M


def _finite(value: float, what: str) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise GeometryError(f"{what} must be finite, got {value}")
    return v


@dataclass(frozen=True, slots=True)
class GeoDatum:
    """A point on the globe: latitude and longitude in degrees (WGS84), ellipsoidal altitude
    in m. A latitude beyond +-90, a longitude beyond +-180, an altitude outside [-1 km, 100 km]
    or a non-finite number is a one-line :class:`~quadnav.errors.GeometryError`."""

    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0

    def __post_init__(self) -> None:
        lat = _finite(self.lat_deg, "the datum's latitude")
        lon = _finite(self.lon_deg, "the datum's longitude")
        alt = _finite(self.alt_m, "the datum's altitude")
        if not -90.0 <= lat <= 90.0:
            raise GeometryError(f"the datum's latitude must lie in [-90, 90] degrees, got {lat}")
        if not -180.0 <= lon <= 180.0:
            raise GeometryError(f"the datum's longitude must lie in [-180, 180] degrees, got {lon}")
        if not MIN_ALT_M <= alt <= MAX_ALT_M:
            raise GeometryError(
                f"the datum's altitude must lie in [{MIN_ALT_M:g}, {MAX_ALT_M:g}] m (ellipsoidal), "
                f"got {alt}"
            )
        object.__setattr__(self, "lat_deg", lat)
        object.__setattr__(self, "lon_deg", lon)
        object.__setattr__(self, "alt_m", alt)

    def as_tuple(self) -> tuple[float, float, float]:
        return self.lat_deg, self.lon_deg, self.alt_m


def enu_heading(yaw_imu_rad: float, yaw_offset_rad: float, declination_rad: float) -> float:
    """The ENU heading (0 east, pi/2 north) of an IMU's or compass's heading reading; see the
    module for the conventions. Wrapped to (-pi, pi]."""
    yaw = _finite(yaw_imu_rad, "the IMU heading") + yaw_offset_rad - declination_rad
    return math.remainder(yaw, 2.0 * math.pi)


@dataclass(frozen=True, slots=True)
class NavSatTransform:
    """Geodetic fixes to a world frame ``W`` and back: ``p_W = Rz(yaw_W_E) p_E + p_W_E`` with
    ``p_E`` the fix in ENU about ``datum`` (see the module)."""

    datum: GeoDatum
    yaw_W_E_rad: float = 0.0
    p_W_E_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    zero_altitude: bool = False
    lever_arm_B_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        _finite(self.yaw_W_E_rad, "the world frame's yaw")
        for name in ("p_W_E_m", "lever_arm_B_m"):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != (3,) or not np.isfinite(v).all():
                raise GeometryError(f"NavSatTransform.{name} must be 3 finite numbers, got {v}")
            object.__setattr__(self, name, tuple(float(x) for x in v))

    @classmethod
    def from_first_fix(
        cls,
        fix: GeoDatum,
        *,
        yaw_imu_rad: float,
        p_W_B_m: ArrayLike = (0.0, 0.0, 0.0),
        yaw_W_B_rad: float = 0.0,
        datum: GeoDatum | None = None,
        yaw_offset_rad: float = 0.0,
        magnetic_declination_rad: float = 0.0,
        zero_altitude: bool = False,
        lever_arm_B_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> NavSatTransform:
        """The transform that puts ``fix`` where the robot is in ``W`` (``p_W_B_m``, facing
        ``yaw_W_B_rad``) at the moment its IMU read ``yaw_imu_rad``. ``datum``: the tangent
        plane's origin (default: the fix itself). Roll and pitch are taken as zero for the
        lever arm at this moment (a robot at rest)."""
        datum = datum or fix
        yaw_E_B = enu_heading(yaw_imu_rad, yaw_offset_rad, magnetic_declination_rad)
        yaw_W_E = math.remainder(_finite(yaw_W_B_rad, "the robot's yaw") - yaw_E_B, 2 * math.pi)
        probe = cls(datum, zero_altitude=zero_altitude)
        p_E_antenna = probe.enu(fix)[0]
        # the body's origin in E: the antenna less its lever arm turned by the heading in E
        p_E_B = p_E_antenna - rot_z(yaw_E_B) @ np.asarray(lever_arm_B_m, dtype=np.float64)
        p_W_B = np.asarray(p_W_B_m, dtype=np.float64)
        if p_W_B.shape != (3,) or not np.isfinite(p_W_B).all():
            raise GeometryError(f"the robot's position must be 3 finite numbers, got {p_W_B}")
        p_W_E = p_W_B - rot_z(yaw_W_E) @ p_E_B
        if zero_altitude:
            p_W_E[2] = 0.0
        return cls(
            datum,
            yaw_W_E_rad=yaw_W_E,
            p_W_E_m=(float(p_W_E[0]), float(p_W_E[1]), float(p_W_E[2])),
            zero_altitude=zero_altitude,
            lever_arm_B_m=lever_arm_B_m,
        )

    # -- geodetic <-> ENU <-> world --------------------------------------------------------
    def enu(self, fixes: GeoDatum | ArrayLike) -> FloatArray:
        """Fixes (a :class:`GeoDatum` or an (N, 3) array of latitude, longitude, altitude) in
        the datum's ENU plane, (N, 3); ``zero_altitude`` sets up to 0."""
        import pymap3d

        lla = np.atleast_2d(
            np.asarray(fixes.as_tuple() if isinstance(fixes, GeoDatum) else fixes, np.float64)
        )
        if lla.shape[1:] != (3,):
            raise GeometryError(
                f"fixes must be (N, 3) latitude, longitude, altitude, got {lla.shape}"
            )
        e, n, u = pymap3d.geodetic2enu(lla[:, 0], lla[:, 1], lla[:, 2], *self.datum.as_tuple())
        out = np.column_stack([e, n, np.zeros_like(u) if self.zero_altitude else u])
        return np.asarray(out, dtype=np.float64)

    def to_world(self, fixes: GeoDatum | ArrayLike, R_W_B: FloatArray | None = None) -> FloatArray:
        """The body's position in ``W`` (N, 3) for each fix; ``R_W_B`` (3, 3) or (N, 3, 3), the
        body's attitude in ``W`` at each fix, takes out the antenna's lever arm (needed when it
        is not zero)."""
        p_W = self.enu(fixes) @ rot_z(self.yaw_W_E_rad).T + np.asarray(self.p_W_E_m)
        lever = np.asarray(self.lever_arm_B_m)
        if lever.any():
            if R_W_B is None:
                raise GeometryError("a GNSS lever arm needs the body's attitude at each fix")
            p_W = p_W - np.einsum("...ij,j->...i", np.asarray(R_W_B, np.float64), lever)
        return np.asarray(p_W, dtype=np.float64)

    def to_geodetic(self, p_W: ArrayLike) -> FloatArray:
        """Points of ``W`` (N, 3) as latitude, longitude and altitude (N, 3), the inverse of
        :meth:`to_world` without lever arm (``zero_altitude``: the datum's altitude plus the
        height in ``W`` above the world origin's)."""
        import pymap3d

        p = np.atleast_2d(np.asarray(p_W, dtype=np.float64))
        if p.shape[1:] != (3,) or not np.isfinite(p).all():
            raise GeometryError(f"points must be (N, 3) and finite, got shape {p.shape}")
        p_E = (p - np.asarray(self.p_W_E_m)) @ rot_z(self.yaw_W_E_rad)
        lat, lon, alt = pymap3d.enu2geodetic(
            p_E[:, 0], p_E[:, 1], p_E[:, 2], *self.datum.as_tuple()
        )
        return np.asarray(np.column_stack([lat, lon, alt]), dtype=np.float64)

    def velocity_to_world(self, v_enu: ArrayLike) -> FloatArray:
        """A GNSS velocity (ENU, (N, 3) or (3,)) in ``W``."""
        v = np.asarray(v_enu, dtype=np.float64)
        return np.asarray(v @ rot_z(self.yaw_W_E_rad).T, dtype=np.float64)
