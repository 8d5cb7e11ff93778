"""PX4 logs from ../shared/data/px4 (pyulog's test logs)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from quadnav.errors import IoError
from quadnav.eval import ape, associate, error_stats
from quadnav.io import read_trajectory
from quadnav.io.ulog import read_ulog_trajectory
from tests.shared_data import PX4_EVENTS as EVENTS
from tests.shared_data import PX4_SITL as SITL
from tests.shared_data import needs

needs_data = needs(SITL)


@needs_data
def test_px4_estimate_follows_the_simulator_ground_truth() -> None:
    est = read_trajectory(SITL)
    gt = read_ulog_trajectory(SITL, groundtruth=True)
    r, e = associate(gt, est, t_max_diff_s=0.02, interpolate=True)
    assert len(e) > 500
    # On the ground in SITL, PX4's estimate stays within a few cm of the truth.
    assert error_stats(ape(r, e))["rmse"] < 0.2


@needs_data
def test_takeoff_is_up_in_enu() -> None:
    tr = read_trajectory(EVENTS)
    assert tr.p_W_B[:, 2].max() > 1.5  # the log takes off to about 2.2 m: up is +z in ENU
    assert np.all(np.diff(tr.t_ns) > 0)


@needs_data
def test_truncated_log_is_an_io_error(tmp_path: Path) -> None:
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(EVENTS.read_bytes()[:3000])
    with pytest.raises(IoError, match=r"cut\.ulg"):
        read_trajectory(cut)
