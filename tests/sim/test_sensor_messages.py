"""A sensor model refusing a parameter names the parameter and its value, not a class
(issue 12, item 24): a library user passed ``sigma_m``, not ``RangeFinder.sigma_m``."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from quadnav.errors import SimError
from quadnav.sim import sensors as s

BAD: list[tuple[Callable[[], object], str]] = [
    (lambda: s.ImuSensor(accel_sigma_m_s2=-1.0, gyro_sigma_rad_s=0.1), "accel_sigma_m_s2"),
    (lambda: s.PositionSensor(sigma_m=0.0, period_ns=10), "sigma_m"),
    (lambda: s.IntegratingImu(period_ns=0, gyro_sigma_rad_s=0.1, accel_sigma_m_s2=0.1), "period_ns"),
    (lambda: s.IntegratingImu(period_ns=1, gyro_sigma_rad_s=0.1, accel_sigma_m_s2=0.1, lever_arm_m=(0.0, 1.0)), "lever_arm_m"),  # type: ignore[arg-type]
    (lambda: s.GpsSensor(datum_lla=(0.0, 0.0, 0.0), period_ns=1, sigma_h_m=-1.0, sigma_v_m=1.0, sigma_vel_m_s=1.0), "-1.0"),
    (lambda: s.MagSensor(period_ns=1, strength=-2.0), "-2.0"),
    (lambda: s.BaroSensor(period_ns=1, sigma_m=-3.0), "-3.0"),
    (lambda: s.RangeFinder(period_ns=1, sigma_m=0.1, min_m=0.05, max_m=0.01), "0.01"),
    (lambda: s.VisionPoseSensor(period_ns=1, sigma_m=0.1, yaw_sigma_rad=-4.0), "-4.0"),
]  # fmt: skip


@pytest.mark.parametrize(("make", "named"), BAD)
def test_sensor_refusal_names_the_parameter_not_the_class(
    make: Callable[[], object], named: str
) -> None:
    with pytest.raises(SimError) as exc:
        make()
    msg = str(exc.value)
    assert named in msg
    assert not any(name in msg for name in s.__all__), msg
