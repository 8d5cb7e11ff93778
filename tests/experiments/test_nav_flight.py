"""The main job's indoor flight, closed loop on the output predictor (2 seeds here; the
20-seed numbers are in the issue note, from `quadnav run --seeds 20`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import EstimationError
from quadnav.eval.metrics import nees
from quadnav.experiments import nav_study
from quadnav.experiments.nav import NavScenario, ground_alignment, run_nav
from quadnav.experiments.nav_study import nav_metrics, run_nav_study
from quadnav.messages import ImuSample, PoseSample

POSE = NavScenario.model_validate({"vision": {"source": "pose"}})


@pytest.fixture(scope="module")
def flights() -> list[dict[str, object]]:
    """The default flight on the pose shortcut (the EKF's numbers; images: test_camera_flight)."""
    return [nav_metrics(run_nav(POSE, seed)) for seed in (0, 1)]


def test_output_predictor_is_centimetre_accurate_with_vision(
    flights: list[dict[str, object]],
) -> None:
    for m in flights:
        assert m.output_rmse_with_vision_m <= 0.02  # type: ignore[operator]


def test_vision_dropouts_are_bridged_and_recovered(flights: list[dict[str, object]]) -> None:
    for m in flights:
        assert len(m.dropout_end_error_m) == 2  # type: ignore[arg-type]
        assert max(m.dropout_end_error_m) <= 0.20  # type: ignore[arg-type]
        assert max(m.dropout_recovery_s) <= 1.0  # type: ignore[arg-type]


def test_filter_is_consistent_in_the_air(flights: list[dict[str, object]]) -> None:
    assert 7.5 <= float(np.mean([m.nees_mean for m in flights])) <= 30.0  # type: ignore[misc]
    for m in flights:
        for frac in m.nis_above_95pct_gate.values():  # type: ignore[attr-defined]
            assert 0.02 <= frac <= 0.10  # about 5 % of innovations beyond the 95 % gate


def test_the_vehicle_lands_where_it_took_off(flights: list[dict[str, object]]) -> None:
    for m in flights:
        x, y, z = m.landed_at_m  # type: ignore[misc]
        assert z == 0.0 and abs(x) < 0.1 and abs(y) < 0.1


def test_ground_alignment_levels_from_gravity_and_heads_from_vision() -> None:
    R_true = Rotation.from_euler("ZYX", [0.7, 0.05, -0.03])
    f = R_true.inv().apply([0.0, 0.0, 9.81])
    imu = [ImuSample(t_ns=k, gyro_rad_s=[0, 0, 0], accel_m_s2=f) for k in range(1, 10)]
    pose = PoseSample(
        t_ns=0,
        p_W_B=[1.0, 2.0, 0.0],
        q_W_B_xyzw=R_true.as_quat(),
        sigma_pos_m=0.01,
        sigma_yaw_rad=0.01,
    )
    R0, p0 = ground_alignment(imu, pose)
    assert (R0.inv() * R_true).magnitude() < 1e-9
    np.testing.assert_allclose(p0, [1.0, 2.0, 0.0])
    with pytest.raises(EstimationError):
        ground_alignment([], pose)


@pytest.mark.slow  # the README's first line and tests/docs/test_run_folders.py make one in CI
def test_run_folder_of_the_main_job(tmp_path: Path) -> None:
    sc = NavScenario.model_validate(
        {
            "plan": {"square_m": 1.0, "hold_s": 1.0},
            "vision": {"dropouts_s": [[4.0, 5.0]], "source": "pose"},
        }
    )
    study = run_nav_study(sc, runs_root=tmp_path)
    d = study.run_dir
    for name in (
        "config.yaml",
        "metrics.json",
        "report.html",
        "positions.csv",
        "delayed.csv",
        "innovations_vision.csv",
        "output.tum",
        "sensors_imu.csv",
        "sensors_vision.csv",
        "sensors_baro.csv",
    ):
        assert (d / name).is_file(), name
    assert (d / "plots" / "errors.png").stat().st_size > 10_000
    assert (d / "plots" / "innovations.png").stat().st_size > 10_000
    import csv

    with (d / "innovations_vision.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    # every fusion is logged with its innovation (position and yaw) and its test ratio
    assert {"innovation_0", "innovation_3", "test_ratio", "accepted"} <= set(rows[0])
    for r in rows:  # the gate is a test ratio of 1
        assert (r["accepted"] in ("1", "True")) == (float(r["test_ratio"]) <= 1.0)
    assert study.summary.output_rmse_with_vision_m <= 0.02


def test_scenario_validation() -> None:
    with pytest.raises(ValueError, match="all disabled"):
        NavScenario.model_validate({"vision": {"enabled": False}, "baro": {"enabled": False}})
    with pytest.raises(ValueError, match="end after"):
        NavScenario.model_validate({"vision": {"dropouts_s": [[3.0, 2.0]]}})


def test_ground_alignment_heading_from_the_magnetometer() -> None:
    from quadnav.messages import VehicleState
    from quadnav.sim.sensors import MagSensor

    R_true = Rotation.from_euler("ZYX", [-1.2, 0.03, 0.02])
    truth = VehicleState(
        t_ns=0,
        p_W_B=np.zeros(3),
        v_W_B=np.zeros(3),
        a_W_B=np.zeros(3),
        q_W_B_xyzw=R_true.as_quat(),
        w_B=np.zeros(3),
    )
    mag = MagSensor(period_ns=1, declination_rad=0.1, noise_sigma=0.0)
    samples = [mag.sample(truth, k, np.random.default_rng(0)) for k in range(0, 10, 2)]
    imu = [
        ImuSample(t_ns=k, gyro_rad_s=[0, 0, 0], accel_m_s2=R_true.apply([0, 0, 9.81], inverse=True))
        for k in range(1, 5)
    ]
    R0, p0 = ground_alignment(
        imu,
        None,
        mag=[s for s in samples if s is not None],
        declination_rad=0.1,
        gps_enu_m=np.array([5.0, 6.0, 0.0]),
    )
    assert (R0.inv() * R_true).magnitude() < 1e-6
    np.testing.assert_allclose(p0, [5.0, 6.0, 0.0])


@pytest.mark.slow  # a long outdoor flight; test_nav_faults.py flies GNSS in CI
def test_outdoor_gps_baro_mag_flight() -> None:
    """One seed of the outdoor built-in (GPS 5 Hz, 200 ms late, 0.5 m; baro; magnetometer)."""
    from quadnav.experiments.scenarios import nav_builtin

    sc = nav_builtin("outdoor_gps")
    m = nav_metrics(run_nav(sc, 0))
    assert m.output_rmse_m <= 0.6 * sc.gps.sigma_h_m  # type: ignore[operator]
    assert m.attitude_rmse_deg <= 1.0  # type: ignore[operator]
    # The gyro bias converges (issue 5 asks for 20 %; over 20 seeds the median is 28 %, seed 0
    # reaches 20.0 %): this guards against losing it, not the final target.
    assert m.bias_error_fraction_60s["gyro"] <= 0.3  # type: ignore[index]
    assert m.sources["gps"].fused > 200  # type: ignore[index]


def test_along_track_heading_turns_towards_travel_at_its_rate_limit() -> None:
    from quadnav.experiments.nav import heading_reference

    dt = 0.01
    v = np.zeros((400, 3))
    v[100:200, 0] = 1.0  # east
    v[200:400, 1] = 1.0  # then north: a 90 degree turn
    yaw = heading_reference(v, dt, "along_track", np.radians(45.0))
    assert np.all(yaw[:200] == 0.0)
    rate = np.abs(np.diff(yaw)) / dt
    assert rate.max() <= np.radians(45.0) + 1e-9
    assert yaw[-1] == pytest.approx(np.pi / 2)  # 2 s of turning at 45 deg/s
    assert yaw[299] == pytest.approx(np.pi / 4)  # half-way after 1 s
    assert np.all(heading_reference(v, dt, "fixed", 1.0) == 0.0)


@pytest.mark.slow  # rendered markers in the loop; the README's `quadnav run` flies them in CI
def test_camera_flight_vision_in_the_loop() -> None:
    """Issue 6: the default flight on rendered images of the marker field (detection, pose with
    covariance, fused with the camera's 250 ms latency): hover within 5 cm of the setpoint."""
    r = run_nav(NavScenario(), 0)
    m = nav_metrics(r)
    assert NavScenario().vision.source == "camera"
    assert m.hold_max_horizontal_error_m <= 0.05
    err = np.linalg.norm(r.output_p - r.truth_p, axis=1)
    hover = (r.truth_p[:, 2] > 1.4) & np.all(np.abs(r.ref_p[:, 0:2]) < 1e-9, axis=1)
    assert np.sqrt(np.mean(err[hover] ** 2)) <= 0.05
    assert m.sources["vision"].fused > 600  # images turned into poses
    assert m.nis_above_95pct_gate["vision"] <= 0.10


def test_the_nees_rows_are_a_view_when_they_are_one_run() -> None:
    """The airborne rows of the NEES: one run is a slice (a view of the covariances, the same
    numbers as the copy a mask takes), anything else the mask itself."""
    run = np.zeros(10, dtype=bool)
    run[3:8] = True
    assert nav_study._rows(run) == slice(3, 8)
    gaps = run.copy()
    gaps[5] = False
    assert nav_study._rows(gaps) is gaps
    none = np.zeros(4, dtype=bool)
    assert nav_study._rows(none) is none
    rng = np.random.default_rng(4)
    A = rng.normal(size=(10, 15, 15))
    P, e = A @ A.transpose(0, 2, 1) + np.eye(15), rng.normal(size=(10, 15))
    np.testing.assert_array_equal(
        nees(e[nav_study._rows(run)], P[nav_study._rows(run)]), nees(e[run], P[run])
    )
