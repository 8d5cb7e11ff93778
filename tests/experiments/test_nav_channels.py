"""The main loop composed from channels and an estimator chosen by config."""

from __future__ import annotations

import numpy as np

from quadnav.experiments.nav import ESTIMATORS, run_nav
from quadnav.experiments.nav_channels import CHANNELS, is_pseudo_source
from quadnav.experiments.nav_study import nav_metrics
from quadnav.experiments.scenarios import nav_builtin
from quadnav.messages import PoseSample

SHORT = ("plan.square_m=1", "plan.hold_s=0.5", "vision.dropouts_s=[[4,5]]")


def test_enabling_the_range_finder_leaves_the_vision_noise_of_a_seed_alone() -> None:
    """Each channel draws from its own stream: flown on the truth (so the path is the same),
    the vision samples of seed 3 are identical with and without the range finder."""
    base = ("vision.source=pose", "closed_loop=false", *SHORT)
    runs = [
        run_nav(nav_builtin("indoor_vision", [*base, f"range.enabled={on}"]), 3, record_stream=True)
        for on in ("false", "true")
    ]
    poses = [[s for s in r.stream or [] if isinstance(s, PoseSample)] for r in runs]
    assert len(poses[0]) > 100 and len(poses[0]) == len(poses[1])
    for a, b in zip(*poses, strict=True):
        assert a.t_ns == b.t_ns
        np.testing.assert_array_equal(a.p_W_B, b.p_W_B)
    assert "range" not in runs[0].sources and runs[1].sources["range"].fused > 50


def test_every_channel_of_a_flight_keeps_its_rate() -> None:
    sc = nav_builtin(
        "indoor_vision",
        [
            "vision.source=pose",
            "vision.rate_hz=30",
            "gps.enabled=true",
            "mag.enabled=true",
            "range.enabled=true",
            "range.rate_hz=70",
            "baro.rate_hz=33",
            "vision.dropouts_s=[]",
            "plan.square_m=1",
            "plan.hold_s=0.5",
        ],
    )
    r = run_nav(sc, 0)
    span_s = sc.flight_s
    rates = {"vision": 30, "baro": 33, "gps": sc.gps.rate_hz, "mag": 50, "imu": 250, "range": 70}
    for name, hz in rates.items():
        n = len(r.sample_times_ns[name])
        if name == "range":  # none while it is closer to the ground than its shortest reading
            assert n <= span_s * hz + 1 and n > 0.7 * span_s * hz
            continue
        assert abs(n - span_s * hz) <= 1.5, (name, n, span_s * hz)


def test_the_truth_estimator_is_chosen_by_config_and_flies_on_the_truth() -> None:
    assert set(ESTIMATORS) == {"ekf", "truth"}
    sc = nav_builtin("indoor_vision", ["vision.source=pose", "estimator.kind=truth", *SHORT])
    r = run_nav(sc, 0)
    np.testing.assert_array_equal(r.output_p, r.truth_p)
    np.testing.assert_array_equal(r.output_q, r.truth_q)
    assert not r.fusion  # nothing fused: the vision and baro samples are counted, unused
    assert r.sources["vision"].rejected_unsupported == r.sources["vision"].received > 50
    assert np.isnan(r.delayed_P).all()  # no covariance: NEES is n/a, not a number
    m = nav_metrics(r)
    assert m.output_rmse_m == 0.0 and str(m.nees_mean).startswith("n/a")


def test_the_zero_velocity_channel_is_a_registered_pseudo_source() -> None:
    assert [e.name for e in CHANNELS][-1] == "imu"  # the IMU moves the clock on last
    assert is_pseudo_source("landed") and not is_pseudo_source("vision")
    assert not is_pseudo_source("something else")


def test_a_surveyed_start_from_the_config_starts_the_flight_there() -> None:
    """``estimator.start_pose`` (heading in degrees) reaches the alignment: the GNSS flight
    starts within the start's sigma of where it stands, not at its first fix (1.5 m noise)."""
    over = ["gps.sigma_h_m=1.5", "gps.sigma_v_m=2.5", *SHORT]
    surveyed = run_nav(nav_builtin("outdoor_gps", [*over, "estimator.start_pose=[0,0,0,0]"]), 0)
    levelled = run_nav(nav_builtin("outdoor_gps", over), 0)
    first = np.flatnonzero(np.isfinite(surveyed.output_p[:, 0]))[0]
    start_err = np.linalg.norm(surveyed.output_p[first] - surveyed.truth_p[first])
    assert start_err < 0.05
    first = np.flatnonzero(np.isfinite(levelled.output_p[:, 0]))[0]
    assert np.linalg.norm(levelled.output_p[first] - levelled.truth_p[first]) > 10 * start_err
