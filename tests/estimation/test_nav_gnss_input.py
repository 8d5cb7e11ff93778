"""Bad GNSS input to the navigation filter (issue 25): a fix stamped before the datum's fix,
a NaN fix, an absurd altitude. Each is refused and counted; none stops the filter."""

from __future__ import annotations

import numpy as np
import pymap3d

from quadnav.estimation import DelayedHorizonEstimator, HorizonConfig
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig
from quadnav.messages import GpsSample, ImuSample
from quadnav.units import GRAVITY_M_S2

DATUM = (-33.8688, 151.2093, 40.0)  # (where the fixes are made; the filter is not told)


def _fix(t_ns: int, east_m: float) -> dict[str, object]:
    lat, lon, alt = pymap3d.enu2geodetic(east_m, 0.0, 0.0, *DATUM)
    return dict(t_ns=t_ns, lat_deg=lat, lon_deg=lon, alt_m=alt, v_enu_m_s=np.zeros(3),
                sigma_h_m=0.5, sigma_v_m=0.5, sigma_vel_m_s=0.1)  # fmt: skip


def test_bad_fixes_are_refused_and_counted_and_the_filter_goes_on() -> None:
    P0 = np.diag([1e-4] * 3 + [0.01] * 3 + [4.0] * 3 + [1e-6] * 3 + [1e-4] * 3)
    ekf = NavEkf(NavEkfConfig(), p0=np.zeros(3), v0=np.zeros(3), q0_xyzw=[0, 0, 0, 1.0], P0=P0)
    est = DelayedHorizonEstimator(
        ekf, HorizonConfig(imu_period_ns=4_000_000, max_delay_ns=200_000_000), t0_ns=0
    )
    for k in range(1, 1001):  # 4 s still
        t = k * 4_000_000
        est.push(ImuSample(t_ns=t, gyro_rad_s=np.zeros(3), accel_m_s2=[0.0, 0.0, GRAVITY_M_S2]))
        if t == 1_000_000_000:  # the first fix: the datum, put where the filter is
            assert est.push_raw(GpsSample, **_fix(t, 0.0))
        elif t == 1_500_000_000:  # stamped 0.4 s before the datum's, 20 m away: too old
            assert est.push_raw(GpsSample, **_fix(600_000_000, 20.0))
        elif t == 2_000_000_000:
            bad = _fix(t, 0.0) | {"lat_deg": float("nan")}
            assert not est.push_raw(GpsSample, **bad)
        elif t == 2_500_000_000:
            assert not est.push_raw(GpsSample, **(_fix(t, 0.0) | {"alt_m": 5.0e6}))
        elif t % 500_000_000 == 0 and t > 1_000_000_000:
            assert est.push_raw(GpsSample, **_fix(t, 0.0))
    stats = est.stats("gps")
    assert stats.rejected_too_old == 1
    assert est.rejected_invalid == {"GpsSample": 2}
    # at 1, 3 and 3.5 s (the 1.5 s one was stale, 2 and 2.5 s bad, 4 s not yet at the horizon)
    assert stats.fused == 3
    # the stale fix 20 m east moved nothing: the filter stays on the datum
    assert np.linalg.norm(ekf.p) < 0.05
