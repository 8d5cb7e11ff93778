"""Infinite, NaN and absurd numbers in scenario configs are refused with the key's name
(issue 12, item 17), before any work or run folder."""

from __future__ import annotations

import pytest

from quadnav.errors import ConfigError
from quadnav.experiments import PlanarConfig
from quadnav.experiments.flight import FlightConfig, builtin_config
from quadnav.experiments.nav import NavScenario
from quadnav.io import load_config

NAV_BAD = [
    ("vision.delay_s=inf", "vision.delay_s", "finite"),
    ("vision.delay_s=.nan", "vision.delay_s", "finite"),
    ("vision.delay_s=1e3", "vision.delay_s", "less than or equal to 10"),
    ("plan.hold_s=1e9", "plan.hold_s", "less than or equal to 3600"),
    # each bound fine alone, the whole flight would last ~3.5 days
    ("plan.square_m=1e5", "plan.speed_m_s", "longer than 3600 s"),
    ("gps.datum_lla=[100,8.5,488]", "gps.datum_lla[0]", "latitude"),
    ("gps.datum_lla=[47,200,488]", "gps.datum_lla[1]", "longitude"),
    ("gps.jitter_s=1", "gps.jitter_s", "unknown key"),
    ("imu.lever_arm_m=[0,0,1e300]", "imu.lever_arm_m[2]", "within +-1e+06"),
    ("estimator.tau_vel_s=-inf", "estimator.tau_vel_s", "finite"),
    ("baro.rate_hz=1e9", "baro.rate_hz", "less than or equal to"),
]


@pytest.mark.parametrize(("override", "key", "why"), NAV_BAD)
def test_nav_scenario_refuses_absurd_numbers_naming_the_key(
    override: str, key: str, why: str
) -> None:
    with pytest.raises(ConfigError) as exc:
        load_config(NavScenario, None, [override])
    msg = str(exc.value)
    assert key in msg and why in msg
    assert "\n" not in msg


@pytest.mark.parametrize(
    ("override", "key", "why"),
    [
        ("duration_s=1e9", "duration_s", "less than or equal to 3600"),
        ("gps.jitter_s=1e9", "gps.jitter_s", "less than or equal to 10"),
        ("gps.delay_s=inf", "gps.delay_s", "finite"),
        ("estimator.max_delay_s=1e6", "estimator.max_delay_s", "less than or equal to 10"),
        ("vehicle.mass_kg=1e300", "vehicle.mass_kg", "within +-1e+06"),
    ],
)
def test_planar_config_refuses_absurd_numbers(override: str, key: str, why: str) -> None:
    with pytest.raises(ConfigError) as exc:
        load_config(PlanarConfig, None, [override])
    assert key in str(exc.value) and why in str(exc.value)


@pytest.mark.parametrize(
    ("override", "key", "why"),
    [
        ("duration_s=inf", "duration_s", "finite"),
        ("duration_s=1e5", "duration_s", "less than or equal to 3600"),
        ("pid_gains.kp_pos=inf", "pid_gains.kp_pos", "valid tuple"),  # three gains, one per axis
        ("pid_gains.kp_pos=[1,1,.nan]", "pid_gains.kp_pos.2", "finite"),
        ("pid_gains.max_vel_m_s=inf", "pid_gains.max_vel_m_s", "finite"),
        ("thesis003.kp_lin=.nan", "thesis003.kp_lin", "finite"),
        ("pid_gains.kp=1", "pid_gains.kp", "unknown key"),
        ("wind.mean_m_s=[1e7,0,0]", "wind.mean_m_s[0]", "within"),
    ],
)
def test_flight_config_refuses_absurd_numbers(override: str, key: str, why: str) -> None:
    with pytest.raises(ConfigError) as exc:
        load_config(FlightConfig, None, [override], base=builtin_config("circle"))
    assert key in str(exc.value) and why in str(exc.value)


def test_reasonable_long_values_still_validate() -> None:
    # the bounds are limits, not the defaults: an hour-long plan and a far datum are fine
    c = load_config(
        NavScenario, None, ["plan.hold_s=300", "gps.datum_lla=[-89.9,-179.9,0]", "vision.delay_s=9"]
    )
    assert c.plan.hold_s == 300 and c.vision.delay_s == 9
    assert c.flight_s < 3600


def test_laps_fly_the_square_again_and_lengthen_the_flight() -> None:
    """``plan.laps``: the square's four corners once per lap between take-off and landing."""
    from quadnav.experiments.scenarios import nav_builtin

    one = nav_builtin("outdoor_gps")
    three = nav_builtin("outdoor_gps", ["plan.laps=3"])
    corners = [tuple(p) for p in three.waypoints().points_m[2:-1]]
    assert corners == [tuple(p) for p in one.waypoints().points_m[2:-1]] * 3
    lap_s = (three.flight_s - one.flight_s) / 2
    # a lap is 80 m at 3 m/s, each of its four legs with its speed-up, slow-down and hold
    assert 80 / 3 < lap_s < 80 / 3 + 4 * (3 / 2 + 3) + 1
    with pytest.raises(ConfigError, match=r"plan\.laps"):
        nav_builtin("outdoor_gps", ["plan.laps=0"])
