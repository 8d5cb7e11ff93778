"""The navigation EKF on the first 150 s of the real KITTI drive in GTSAM's wheel: fixes it
was not given (held out) are where it says the car was."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav.errors import QuadnavError
from quadnav.experiments.kitti_gps import KittiGpsConfig, horizontal_errors_at, run_kitti_gps
from quadnav.io.gtsam_kitti import GtsamKitti, read_gtsam_kitti


def _data() -> GtsamKitti | None:
    try:
        return read_gtsam_kitti()
    except QuadnavError:
        return None


DATA = _data()
pytestmark = pytest.mark.skipif(DATA is None, reason="GTSAM's Data folder (KITTI files) absent")
SECONDS = 150.0


def _held_out_rmse(every: int) -> tuple[float, int, float]:
    """(RMSE of the held-out fixes, fixes refused, RMSE of a constant-velocity guess from the
    two latest fixes given, the causal thing to do without an IMU)."""
    assert DATA is not None
    r = run_kitti_gps(DATA, KittiGpsConfig(gps_every=every, duration_s=SECONDS))
    err = horizontal_errors_at(r.t_ns, r.p, DATA.gps_t_ns, DATA.gps_p_m)
    held = ~np.isnan(err)
    held[:3] = False  # the start and the two fixes it started from
    held[r.given] = False
    base = []
    known = sorted({1, 2, *r.given.tolist()})
    for k in np.flatnonzero(held).tolist():
        a, b = [i for i in known if i < k][-2:]
        tk, ta, tb = (DATA.gps_t_ns[[k, a, b]] * 1e-9).tolist()
        v = (DATA.gps_p_m[b] - DATA.gps_p_m[a]) / (tb - ta)
        base.append(np.hypot(*(DATA.gps_p_m[b] + v * (tk - tb) - DATA.gps_p_m[k])[:2]))
    rmse = float(np.sqrt(np.mean(err[held] ** 2)))
    return rmse, len(r.refused), float(np.sqrt(np.mean(np.square(base))))


def test_every_other_fix_predicts_the_ones_between() -> None:
    rmse, refused, straight = _held_out_rmse(2)
    # a fix 1 s after the last one given: within 1 m (under 4 GPS sigmas of 0.26 m; the car
    # moves 5 to 12 m in that second), and far better than a straight line
    assert refused == 0
    assert rmse < 1.0
    assert rmse < 0.5 * straight


def test_gtsams_fixes_every_10_s_beat_dead_reckoning_and_a_straight_line() -> None:
    rmse, refused, straight = _held_out_rmse(10)
    dead_reckoning, _, _ = _held_out_rmse(0)
    # up to 9 s from the last fix given the car travels some 80 m and turns corners
    assert refused == 0
    assert rmse < 15.0
    assert rmse < 0.5 * straight
    assert rmse < 0.01 * dead_reckoning
