"""Issue 25: GPS fused with a drifting odometry (the VIO's shortcut), against each alone and
against thesis 003's configuration, with a GPS glitch, a 30 s outage and an odometry reset.
Each flight is outdoor_vio_gps_odometry's square (20 m at 3 m/s, about 60 s): seed 0 in CI,
seed 1 too with ``pytest -m slow`` (each seed is three 60 s flights, 40 s of one core)."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav.experiments.nav import NavRunResult, run_nav
from quadnav.experiments.nav_study import nav_metrics
from quadnav.experiments.scenarios import nav_builtin

SEEDS = (0,)
MORE_SEEDS = (1,)  # pytest -m slow
_NAMES = ("outdoor_vio_gps_odometry", "outdoor_gps_2hz", "outdoor_vio_gps_thesis003")


def _rmse(r: NavRunResult) -> float:
    return float(nav_metrics(r).output_rmse_m)


def _flown(seeds: tuple[int, ...]) -> dict[str, list[NavRunResult]]:
    return {n: [run_nav(nav_builtin(n), s) for s in seeds] for n in _NAMES}


@pytest.fixture(scope="module")
def flights() -> dict[str, list[NavRunResult]]:
    return _flown(SEEDS)


@pytest.mark.slow  # three more 60 s flights: the two tests below on another seed
def test_the_fusion_and_the_thesis_configuration_on_another_seed() -> None:
    more = _flown(MORE_SEEDS)
    test_the_fusion_beats_the_odometry_and_the_gps_alone(more)
    test_the_thesis_configuration_is_no_better_than_the_odometry(more)


def test_the_fusion_beats_the_odometry_and_the_gps_alone(
    flights: dict[str, list[NavRunResult]],
) -> None:
    """Position RMSE of the fusion at most 0.7 times the better of the odometry alone (from its
    first state) and the GPS alone (the same flight on GPS and IMU), seed by seed; and below
    the position-only random-walk reference tuned after the fact (``vio_gps_reference_m``):
    this odometry's drift is the EKF's model (its heading and scale too), and the EKF has the
    GPS's velocity (seeds 0 and 1: 0.27 and 0.21 m against 0.37 and 0.43)."""
    for fused, gps in zip(
        flights["outdoor_vio_gps_odometry"], flights["outdoor_gps_2hz"], strict=True
    ):
        vio_alone = nav_metrics(fused).vio_alone_m
        assert isinstance(vio_alone, float)
        better = min(vio_alone, _rmse(gps))
        assert _rmse(fused) <= 0.7 * better, (fused.seed, _rmse(fused), vio_alone, _rmse(gps))
        reference = nav_metrics(fused).vio_gps_reference_m
        assert isinstance(reference, float) and reference < vio_alone
        assert _rmse(fused) < reference, (fused.seed, _rmse(fused), reference)


def test_the_thesis_configuration_is_no_better_than_the_odometry(
    flights: dict[str, list[NavRunResult]],
) -> None:
    """Thesis 003's robot_localization set-up (both as absolute fixes of one frame) gains at
    most a quarter on the odometry alone (over 20 seeds it was worse on 8), and is at least 1.5
    times our fusion's error. The mechanism: the drifting frame's poses, taken as fixes at their centimetre sigmas, make the
    filter sure of a position that is off by the drift, so the GPS's disagreement is put down
    to its noise: its NEES is over ten times that of the fusion, which estimates the drift."""
    for thesis, ours in zip(
        flights["outdoor_vio_gps_thesis003"], flights["outdoor_vio_gps_odometry"], strict=True
    ):
        vio_alone = nav_metrics(thesis).vio_alone_m
        assert isinstance(vio_alone, float)
        assert _rmse(thesis) >= 0.75 * vio_alone
        assert _rmse(thesis) >= 1.5 * _rmse(ours)
        assert nav_metrics(thesis).nees_mean > 10 * nav_metrics(ours).nees_mean


def test_a_gps_glitch_beside_the_odometry_is_refused_and_counted() -> None:
    """20 m for 3 s at 2 Hz: six fixes, each refused; the odometry holds the position, and the
    glitch does not reset it after 2 s of refusals (the odometry's position is being fused)."""
    r = run_nav(nav_builtin("outdoor_vio_gps_glitch"), 0)
    m = nav_metrics(r)
    assert m.sources["gps"].rejected_gate == 6
    assert not any("gps: rejected" in msg for _, msg in r.events)
    t = r.t_ns * 1e-9
    err = np.linalg.norm(r.output_p - r.truth_p, axis=1)
    assert err[(t > 25) & (t < 29)].max() < 0.6
    assert m.output_rmse_m < 0.4


def test_a_30_s_outage_grows_no_faster_than_the_odometry_drifts() -> None:
    """GPS out from 15 to 45 s: the fused error's growth over the outage stays within the
    odometry's own drift over it (its frame's random walk and its yaw's turn of the path)."""
    r = run_nav(nav_builtin("outdoor_vio_gps_outage"), 0)
    v = r.vio
    assert v is not None
    t, tv = r.t_ns * 1e-9, v.t_ns * 1e-9
    err = np.linalg.norm(r.output_p - r.truth_p, axis=1)
    odo_err = np.linalg.norm(v.p_W_B - v.truth_p_W_B, axis=1)
    grew = err[np.searchsorted(t, 44.5)] - err[np.searchsorted(t, 15.0)]
    odo_grew = np.abs(odo_err[np.searchsorted(tv, 44.5)] - odo_err[np.searchsorted(tv, 15.0)])
    assert grew <= max(odo_grew, 0.0) + 0.25, (grew, odo_grew)
    assert nav_metrics(r).sources["gps"].fused < 0.6 * 2 * t[-1]  # 30 s of 60 without fixes


def test_an_odometry_reset_re_anchors_without_a_jump() -> None:
    """At 30 s the odometry restarts at zero with a new heading: the filter re-anchors its
    frame and says so; the output moves by no more than a flight step's worth."""
    r = run_nav(nav_builtin("outdoor_vio_gps_reset"), 0)
    assert any("vio: reset counter 1, frame re-anchored" in msg for _, msg in r.events)
    err = r.output_p - r.truth_p
    t = r.t_ns * 1e-9
    k = np.searchsorted(t, 30.0)
    assert np.linalg.norm(err[k + 50] - err[k - 50]) < 0.15
    assert nav_metrics(r).output_rmse_m < 0.4


@pytest.mark.slow  # ten 60 s flights with the rendered VIO: about 3 minutes on one core
def test_on_realistic_sensors_the_fusion_is_at_most_0_7x_the_better_alone() -> None:
    """outdoor_vio_gps_realistic (the real VIO on rendered images, realistic sensors, its
    frame's drift rate chosen on seeds 0-4) on seeds 5-9, which did not choose it, against the
    VIO alone and the GPS alone (the same flight on GPS and IMU, from the same surveyed pad).

    The fused RMSE's median is at most 0.7x the better of the two alone's medians (0.62 at
    7105bc5, 0.60 at 17944b2). It is under the GPS alone's on every seed (at most 0.91x) and
    under the VIO alone's in the median (0.54, 0.50). The NEES's median is within 20 % of the
    15 states (15.7 both times).

    The per-seed ratio to whichever of the two did better on that seed is not asserted. Its
    median moved from 0.63 to 0.86 between those commits, whose flights differ by 1e-13: the
    VIO's drift on a seed, closed in the loop, is chaotic (see
    docs/results/2026-12-04-issue26-ten-minutes.md)."""
    fused_rmse, vio_alone, gps_alone, nees = [], [], [], []
    for seed in range(5, 10):
        fused = run_nav(nav_builtin("outdoor_vio_gps_realistic"), seed)
        gps = run_nav(nav_builtin("outdoor_gps_2hz", ["estimator.start_pose=[0,0,0,0]"]), seed)
        m = nav_metrics(fused)
        assert isinstance(m.vio_alone_m, float)
        fused_rmse.append(_rmse(fused))
        vio_alone.append(m.vio_alone_m)
        gps_alone.append(_rmse(gps))
        nees.append(m.nees_mean)
    f, v, g = np.median(fused_rmse), np.median(vio_alone), np.median(gps_alone)
    assert f <= 0.7 * min(v, g), (fused_rmse, vio_alone, gps_alone)
    assert all(a < b for a, b in zip(fused_rmse, gps_alone, strict=True)), (fused_rmse, gps_alone)
    assert np.median(np.divide(fused_rmse, vio_alone)) <= 0.7, (fused_rmse, vio_alone)
    assert 12.0 <= np.median(nees) <= 18.0, nees


def test_the_reference_names_why_it_is_missing_instead_of_ending_the_run() -> None:
    """An odometry with two states at one time (or a flight without GPS) gives the reference
    as n/a with the reason; the flight's other metrics are not lost to it."""
    from quadnav.experiments.nav_study import _gps_reference
    from quadnav.experiments.vio_flight import VioRecord

    n = 5
    level = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    v = VioRecord(
        t_ns=np.array([0, 1, 1, 2, 3], dtype=np.int64) * 100_000_000,
        p_W_B=np.zeros((n, 3)), q_W_B_xyzw=level, reset_counter=np.zeros(n, dtype=np.int64),
        truth_p_W_B=np.zeros((n, 3)), truth_q_W_B_xyzw=level,
    )  # fmt: skip
    out = _gps_reference(nav_builtin("outdoor_vio_gps_odometry"), v)
    assert str(out["vio_gps_reference_m"]).startswith("n/a: ")
    assert "must increase" in str(out["vio_gps_reference_m"])
    no_gps = _gps_reference(nav_builtin("indoor_vio_odometry"), v)
    assert no_gps["vio_gps_reference_m"] == "n/a: no GPS"
