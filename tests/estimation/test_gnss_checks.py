"""PX4's GNSS quality checks (EKF2_GPS_CHECK, EKF2_REQ_*): which fixes may be fused."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav.errors import EstimationError
from quadnav.estimation.gnss_checks import GnssCheckConfig, run_gnss_checks


def fixes(n: int, **over: np.ndarray) -> dict[str, np.ndarray]:
    """``n`` good fixes at 5 Hz of a receiver standing still."""
    g = {"t_ns": np.arange(n, dtype=np.int64) * 200_000_000, "lat": np.full(n, 47.0), "lon": np.full(n, 8.0),
         "alt": np.full(n, 500.0), "v_enu": np.zeros((n, 3)), "eph": np.full(n, 1.0), "epv": np.full(n, 1.5),
         "s_var": np.full(n, 0.2), "fix": np.full(n, 3), "nsats": np.full(n, 12), "pdop": np.full(n, 1.2)}  # fmt: skip
    g.update(over)
    return g


def test_good_fixes_are_used_only_after_passing_for_the_required_time() -> None:
    g = fixes(100)  # 20 s
    r = run_gnss_checks(g, np.ones(100, bool), GnssCheckConfig(pass_s=10.0))
    first = int(np.flatnonzero(r.usable)[0])
    assert g["t_ns"][first] * 1e-9 == pytest.approx(10.2)  # more than 10 s after the first fix
    assert r.usable[first:].all() and r.reasons(0) == ("not_yet_passed_long_enough",)
    # once qualified, PX4 applies the coarse limits only (50 m, 10 m/s), and a failure costs
    # max(1 s, pass_s / 10) of passing again
    eph = np.full(100, 1.0)
    eph[70] = 3.5
    eph[80:83] = 60.0
    r = run_gnss_checks(fixes(100, eph=eph), np.ones(100, bool), GnssCheckConfig(pass_s=10.0))
    assert r.usable[70] and not r.usable[80:83].any() and "eph" in r.reasons(81)
    assert not r.usable[83:88].any() and r.usable[88:].all()  # 1 s after the last failure


@pytest.mark.parametrize(
    ("key", "value", "reason", "bit"),
    [("nsats", 5, "satellites", 0), ("pdop", 3.0, "pdop", 1), ("eph", 3.5, "eph", 2),
     ("epv", 6.0, "epv", 3), ("s_var", 0.8, "speed_accuracy", 4), ("fix", 2, "fix_type", None)],
)  # fmt: skip
def test_each_receiver_figure_is_checked_when_its_bit_is_set(
    key: str, value: float, reason: str, bit: int | None
) -> None:
    n = 150
    bad = fixes(n)[key].copy()
    bad[20:40] = value  # bad fixes from 4 to 8 s
    g = fixes(n, **{key: bad})
    r = run_gnss_checks(g, np.ones(n, bool), GnssCheckConfig(mask=511))
    assert reason in r.reasons(30) and not r.usable[:90].any()
    assert (
        r.t_qualified_ns is not None and r.t_qualified_ns * 1e-9 > 17.8
    )  # 10 s after the last bad
    if bit is not None:  # with the bit cleared the check is not applied
        r0 = run_gnss_checks(g, np.ones(n, bool), GnssCheckConfig(mask=511 & ~(1 << bit)))
        assert r0.t_qualified_ns is not None and r0.t_qualified_ns * 1e-9 < 10.5


def test_fixes_drifting_while_at_rest_are_never_used() -> None:
    """A receiver on a vehicle standing still whose fixes wander metres (multipath): PX4's
    drift checks refuse it however good it says it is."""
    n = 300  # 60 s at 5 Hz
    rng = np.random.default_rng(3)
    w = 2 * np.pi / 30.0 * np.arange(n) * 0.2  # a 3 m circle every 30 s, and noise
    north_m = 3.0 * np.sin(w) + rng.normal(0.0, 0.3, n)
    east_m = 3.0 * np.cos(w) + rng.normal(0.0, 0.3, n)
    lat = 47.0 + np.degrees(north_m / 6_371_000.0)
    g = fixes(n, lat=lat, lon=8.0 + np.degrees(east_m / (6_371_000.0 * np.cos(np.radians(47.0)))))
    r = run_gnss_checks(g, np.ones(n, bool), GnssCheckConfig())
    assert not r.usable.any() and r.t_qualified_ns is None
    assert r.refused_counts().get("horizontal_drift", 0) > 200
    # in the air the drift checks do not apply: the same fixes pass
    assert run_gnss_checks(g, np.zeros(n, bool), GnssCheckConfig()).usable.sum() > 200


def test_vertical_speed_while_landed_is_checked_when_selected() -> None:
    n = 150
    v = np.zeros((n, 3))
    v[:, 2] = 0.5  # a receiver reporting 0.5 m/s up at rest
    g = fixes(n, v_enu=v)
    assert "vertical_speed" in run_gnss_checks(
        g, np.ones(n, bool), GnssCheckConfig(mask=511)
    ).reasons(100)
    assert run_gnss_checks(g, np.ones(n, bool), GnssCheckConfig(mask=245)).usable[100]


def test_bad_limits_are_refused() -> None:
    with pytest.raises(EstimationError, match="max_eph_m"):
        GnssCheckConfig(max_eph_m=0.0)
