"""Physical constants and unit conversions shared by every layer (it imports nothing).

Time inside quadnav is integer nanoseconds; configuration speaks seconds. :func:`s_to_ns` is the
one place a duration or a time stamp in seconds becomes nanoseconds.
"""

from __future__ import annotations

__all__ = ["GNSS_ALT_RANGE_M", "GRAVITY_M_S2", "NS_PER_S", "ns_to_s", "s_to_ns"]

#: Standard gravity (m/s^2), the value PX4 uses (``CONSTANTS_ONE_G``).
GRAVITY_M_S2 = 9.80665
NS_PER_S = 1_000_000_000
#: The ellipsoidal altitudes (m) a GNSS fix or datum may have: the Dead Sea shore is about
#: 430 m below the sea and the geoid within about 110 m of the ellipsoid; beyond 100 km is a
#: unit or sign mistake, not a place.
GNSS_ALT_RANGE_M = (-1_000.0, 100_000.0)


def s_to_ns(t_s: float) -> int:
    """Seconds to integer nanoseconds, rounded to the nearest."""
    return round(t_s * 1e9)


def ns_to_s(t_ns: int) -> float:
    """Integer nanoseconds to seconds."""
    return t_ns * 1e-9
