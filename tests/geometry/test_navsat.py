"""The navsat transform where robot_localization's users trip: a southern-hemisphere datum,
the antimeridian, an IMU whose zero heading is north, the declination's sign, a datum given by
hand, a robot turning in place with an offset antenna; and a datum off the globe refused."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import GeometryError
from quadnav.geometry.navsat import GeoDatum, NavSatTransform, enu_heading

# Metres per degree of latitude near -34 degrees (WGS84's meridian arc), to 1e-4 relative.
M_PER_DEG_LAT_34S = 110_942.0


def _moved(d: GeoDatum, north_m: float, east_m: float) -> GeoDatum:
    """A point ``north_m`` and ``east_m`` from ``d`` by the spherical small-offset formula, an
    independent check of pymap3d's tangent plane (exact enough over 100 m for 1 mm)."""
    lat = d.lat_deg + north_m / M_PER_DEG_LAT_34S
    m_per_deg_lon = M_PER_DEG_LAT_34S * math.cos(math.radians(d.lat_deg)) * 1.00336
    return GeoDatum(lat, d.lon_deg + east_m / m_per_deg_lon, d.alt_m)


def test_a_southern_hemisphere_datum_gives_north_as_plus_y() -> None:
    sydney = GeoDatum(-33.8688, 151.2093, 40.0)
    t = NavSatTransform(sydney)
    p = t.to_world(_moved(sydney, north_m=100.0, east_m=0.0))[0]
    assert p[1] == pytest.approx(100.0, rel=2e-4) and abs(p[0]) < 1e-6
    p = t.to_world(_moved(sydney, north_m=0.0, east_m=50.0))[0]
    assert p[0] == pytest.approx(50.0, rel=3e-3) and abs(p[1]) < 0.01
    # round trip to the globe and back, to a tenth of a millimetre
    pts = np.array([[10.0, -20.0, 3.0], [-500.0, 250.0, -2.0]])
    np.testing.assert_allclose(t.to_world(t.to_geodetic(pts)), pts, atol=1e-4)


def test_the_antimeridian_is_a_step_not_a_world() -> None:
    d = GeoDatum(-16.5, 179.9995, 0.0)  # Fiji: UTM changes zone here, the tangent plane does not
    p = NavSatTransform(d).to_world([[-16.5, -179.9995, 0.0]])[0]
    step = 0.001 * 111_320.0 * math.cos(math.radians(16.5))  # 0.001 degrees of longitude east
    assert p[0] == pytest.approx(step, rel=0.01) and abs(p[1]) < 0.01


@pytest.mark.parametrize(
    ("yaw_offset", "declination", "reading", "expected"),
    [
        (0.0, 0.0, 0.0, 0.0),  # REP-103: zero faces east
        (math.pi / 2, 0.0, 0.0, math.pi / 2),  # zero faces north: facing north it reads 0
        (0.0, math.radians(10.0), math.pi / 2, math.radians(80.0)),  # magnetic north, 10 deg E
        (math.pi / 2, math.radians(-5.0), 0.0, math.radians(95.0)),  # both, west declination
    ],
)
def test_headings_from_the_imu(
    yaw_offset: float, declination: float, reading: float, expected: float
) -> None:
    assert enu_heading(reading, yaw_offset, declination) == pytest.approx(expected, abs=1e-12)


def test_an_imu_whose_zero_is_north_puts_a_fix_ahead_on_plus_x() -> None:
    """The robot stands at the world's origin facing its +x; its IMU (zero facing north) reads
    0: it faces north. A fix 10 m north of it is 10 m ahead, on +x of the world."""
    start = GeoDatum(51.5, -0.12, 30.0)
    t = NavSatTransform.from_first_fix(start, yaw_imu_rad=0.0, yaw_offset_rad=math.pi / 2)
    ten_m_north = NavSatTransform(start).to_geodetic([[0.0, 10.0, 0.0]])
    np.testing.assert_allclose(t.to_world(ten_m_north)[0], [10.0, 0.0, 0.0], atol=1e-6)
    # told the IMU's zero faced east, the same fix would land 10 m to the robot's left
    east = NavSatTransform.from_first_fix(start, yaw_imu_rad=0.0)
    np.testing.assert_allclose(east.to_world(ten_m_north)[0], [0.0, 10.0, 0.0], atol=1e-6)


def test_a_datum_by_hand_and_a_robot_away_from_the_world_origin() -> None:
    """The tangent plane's origin 300 m from where the robot starts; the robot at (5, -2, 0) in
    its world, facing 30 degrees, its IMU true-heading REP-103 reading 120 degrees. A fix
    20 m east of the robot (in ENU) is then 20 m along the world direction 30 - 120 degrees."""
    datum = GeoDatum(-45.0, 170.0, 100.0)
    plane = NavSatTransform(datum)
    robot_E = np.array([200.0, -224.0, 1.5])
    fix = GeoDatum(*plane.to_geodetic(robot_E)[0])
    t = NavSatTransform.from_first_fix(
        fix, yaw_imu_rad=math.radians(120.0), p_W_B_m=(5.0, -2.0, 0.0),
        yaw_W_B_rad=math.radians(30.0), datum=datum,
    )  # fmt: skip
    np.testing.assert_allclose(t.to_world(fix)[0], [5.0, -2.0, 0.0], atol=1e-6)
    later = plane.to_geodetic(robot_E + [20.0, 0.0, 0.0])
    a = math.radians(30.0 - 120.0)
    np.testing.assert_allclose(
        t.to_world(later)[0], [5.0 + 20 * math.cos(a), -2.0 + 20 * math.sin(a), 0.0], atol=1e-5
    )
    np.testing.assert_allclose(
        t.to_world(t.to_geodetic([[1.0, 2.0, 3.0]])), [[1.0, 2.0, 3.0]], atol=1e-6
    )
    assert t.velocity_to_world([1.0, 0.0, 0.0]) == pytest.approx([math.cos(a), math.sin(a), 0.0])


def test_turning_in_place_with_the_antenna_ahead_stays_in_place() -> None:
    """An antenna 0.5 m ahead of the body: its fixes draw a circle 1 m across as the robot
    turns on the spot; with the lever arm taken out the body stays within a millimetre."""
    datum = GeoDatum(-33.0, -70.6, 500.0)
    plane = NavSatTransform(datum)
    lever = (0.5, 0.0, 0.0)
    t = NavSatTransform.from_first_fix(
        GeoDatum(*plane.to_geodetic([[0.5, 0.0, 0.0]])[0]), yaw_imu_rad=0.0, lever_arm_B_m=lever
    )
    yaws = np.linspace(0.0, 2 * math.pi, 37)
    R = Rotation.from_euler("z", yaws[:, None]).as_matrix()
    antenna_E = np.column_stack([0.5 * np.cos(yaws), 0.5 * np.sin(yaws), np.zeros_like(yaws)])
    fixes = plane.to_geodetic(antenna_E)
    raw = NavSatTransform.from_first_fix(GeoDatum(*fixes[0]), yaw_imu_rad=0.0).to_world(fixes)
    assert np.ptp(raw[:, 0]) == pytest.approx(1.0, abs=1e-3)
    body = t.to_world(fixes, R_W_B=R)
    assert np.abs(body).max() < 1e-3
    with pytest.raises(GeometryError, match="lever arm needs the body's attitude"):
        t.to_world(fixes)


@pytest.mark.parametrize(
    ("lat", "lon", "alt", "says"),
    [
        (91.0, 0.0, 0.0, "latitude must lie in"),
        (0.0, 181.0, 0.0, "longitude must lie in"),
        (0.0, 0.0, 6.4e6, "altitude must lie in"),
        (math.nan, 0.0, 0.0, "latitude must be finite"),
        (0.0, math.inf, 0.0, "longitude must be finite"),
    ],
)
def test_a_datum_off_the_globe_is_one_line(lat: float, lon: float, alt: float, says: str) -> None:
    with pytest.raises(GeometryError, match=says) as err:
        GeoDatum(lat, lon, alt)
    assert "\n" not in str(err.value)


def test_zero_altitude_flattens_every_fix() -> None:
    d = GeoDatum(10.0, 10.0, 0.0)
    t = NavSatTransform(d, zero_altitude=True)
    assert t.to_world([[10.0, 10.0, 250.0], [10.001, 10.0, -3.0]])[:, 2] == pytest.approx([0, 0])
