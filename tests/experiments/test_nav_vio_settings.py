"""Issue 21, item 10: ``quadnav run indoor_vio`` takes the VIO's own settings in its ``vio``
section (``--set vio.keyframe_parallax_px=...``), validated as ``VioConfig``; a scenario that
runs no VIO refuses them, as it refuses the rest of a ``vio`` section it would not read."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.errors import ConfigError
from quadnav.experiments.nav_config import NavScenario
from quadnav.experiments.scenarios import nav_builtin
from quadnav.experiments.vio_flight import VioCameraSensor, build_vio_sensor
from quadnav.io.config import dump_config, load_config
from quadnav.vio.config import VioConfig
from quadnav.vio.estimator import VioEstimator


def test_the_vio_settings_reach_the_estimator() -> None:
    sc = nav_builtin("indoor_vio", ["vio.keyframe_parallax_px=24.5", "vio.tracker.max_features=90"])
    rng = np.random.default_rng(0)
    sensor = build_vio_sensor(sc, rng, rng, 9.81, None)
    assert isinstance(sensor, VioCameraSensor) and isinstance(sensor.vio, VioEstimator)
    cfg = sensor.vio.config
    assert cfg.keyframe_parallax_px == 24.5 and cfg.tracker.max_features == 90
    # the rest is VioConfig's defaults (the estimator was given the section's VIO part)
    assert cfg.window_keyframes == VioConfig().window_keyframes


@pytest.mark.parametrize(
    ("scenario", "override", "named"),
    [
        ("indoor_vio", "vio.keyframe_parallax_px=-1", "vio.keyframe_parallax_px"),
        ("indoor_vio", "vio.keyframe_parallax=16", "vio.keyframe_parallax: unknown key"),
        ("indoor_vio", "vio.tracker.max_features=abc", "vio.tracker.max_features"),
        # no VIO: its settings, and any other of the vio section, are refused, not ignored
        ("indoor_vision_pose", "vio.keyframe_parallax_px=20", "vio.keyframe_parallax_px is set"),
        ("outdoor_gps", "vio.sigma_m=0.1", "vio.sigma_m is set"),
        # the odometry shortcut runs no VIO: the VIO's own settings are refused
        ("indoor_vio_odometry", "vio.window_keyframes=12", "vio.window_keyframes is a setting"),
        # ... and the VIO on rendered images does not read the shortcut's noise
        ("indoor_vio", "vio.sigma_m=0.1", "vio.sigma_m is a setting of the odometry shortcut"),
        ("indoor_vio", "vio.rate_hz=30", "vio.rate_hz is a setting of the odometry shortcut"),
        # how the EKF takes the odometry (issue 22, item 5): named, validated, not ignored
        ("indoor_vio", "vio.odometry_mode=delta", "vio.odometry_mode: Input should be 'absolute'"),
        ("indoor_vio", "vio.frame_drift_m_sqrt_s=0", "vio.frame_drift_m_sqrt_s: Input should be"),
        (
            "indoor_vio_odometry",
            ["vio.odometry_mode=absolute", "vio.frame_drift_yaw_rad_sqrt_s=0.01"],
            "vio.frame_drift_yaw_rad_sqrt_s is a setting of vio.odometry_mode=relative",
        ),
        (
            "indoor_vio_odometry",
            ["vio.odometry_mode=absolute", "vio.frame_drift_from_covariance=true"],
            "vio.frame_drift_from_covariance is a setting of vio.odometry_mode=relative",
        ),
        ("indoor_vio", "vio.frame_drift_from_covariance=2", "vio.frame_drift_from_covariance:"),
        # loop closure and maps (issue 23, item 6): the VIO's, not the shortcut's
        ("indoor_vio_odometry", "vio.loop=true", "vio.loop is a setting of the VIO, which"),
        ("indoor_vio", "vio.save_map=true", "vio.save_map saves loop closure's map: set vio.loop"),
        ("indoor_vio", "vio.load_map=/nonexistent/map", "vio.load_map /nonexistent/map: no such"),
        ("indoor_vio", "vio.loop=maybe", "vio.loop: Input should be a valid boolean"),
        (
            "indoor_vio",
            ["vio.final_smoothing=true", "vio.load_map=."],
            "vio.final_smoothing: not with vio.load_map",
        ),
        # the SLAM as the odometry (issue 24, item 7): a stereo rig, none of the VIO's settings
        ("indoor_slam", "vio.rig=thesis003_sim", "vio.odometry=slam needs a stereo rig"),
        ("indoor_slam", "vio.window_keyframes=12", "vio.window_keyframes is a setting of the VIO"),
        ("indoor_slam", "vio.loop=true", "which vio.odometry=slam does not run (the SLAM closes"),
        ("indoor_slam", "vio.odometry=orb", "vio.odometry: Input should be 'vio' or 'slam'"),
        ("indoor_vio_odometry", "vio.odometry=slam", "vio.odometry is a setting of the VIO"),
        ("indoor_slam", "vio.camera_rate_hz=30", "vio.camera_rate_hz 30 is faster than vio.rig"),
        (
            "indoor_vio_odometry",
            ["estimator.vision_frame=rotate", "mag.enabled=true"],
            "vio.odometry_mode=relative estimates the odometry frame's yaw drift",
        ),
    ],
)
def test_a_bad_or_unused_vio_setting_is_one_line_naming_it(
    tmp_path: Path, scenario: str, override: str | list[str], named: str
) -> None:
    sets = [
        x for o in ([override] if isinstance(override, str) else override) for x in ("--set", o)
    ]
    result = CliRunner().invoke(app, ["run", scenario, *sets, "--out", str(tmp_path)])
    assert result.exit_code == 2, result.output
    out = result.output.strip()
    assert "Traceback" not in out and len(out.splitlines()) == 1
    assert named in out
    assert not any(tmp_path.iterdir())  # refused before any run folder


def test_the_shortcut_keeps_its_own_vio_settings() -> None:
    sc = nav_builtin("indoor_vio_odometry", ["vio.sigma_m=0.05", "vio.world=room"])
    assert sc.vio.sigma_m == 0.05
    with pytest.raises(ConfigError, match=r"vio\.keyframe_parallax_px is a setting"):
        nav_builtin("indoor_vio_odometry", ["vio.keyframe_parallax_px=20"])


@pytest.mark.parametrize("scenario", ["indoor_vision", "indoor_vio", "indoor_vio_odometry"])
def test_a_resolved_config_loads_back(tmp_path: Path, scenario: str) -> None:
    """A run folder's config.yaml holds every key, the vio section's defaults too: it loads."""
    sc = nav_builtin(scenario, ["vio.keyframe_parallax_px=20"] if scenario == "indoor_vio" else [])
    path = tmp_path / "config.yaml"
    path.write_text(dump_config(sc))
    assert "keyframe_parallax_px" in yaml.safe_load(path.read_text())["vio"]
    assert load_config(NavScenario, path) == sc


def test_a_corrupt_map_is_one_line_before_any_flight(tmp_path: Path) -> None:
    bad = tmp_path / "map"
    bad.mkdir()
    (bad / "map.json").write_text("{ not json")
    out = tmp_path / "runs"
    result = CliRunner().invoke(
        app, ["run", "indoor_vio", "--set", f"vio.load_map={bad}", "--out", str(out)]
    )
    assert result.exit_code != 0
    text = result.output.strip()
    assert "Traceback" not in text and len(text.splitlines()) == 1, text
    assert f"vio.load_map {bad}: map.json is corrupt" in text
    assert not out.exists() or not any(out.iterdir())


def test_loop_closure_wraps_the_vio_and_the_ekf_follows_it() -> None:
    from quadnav.estimation.nav_filter import AligningNavFilter
    from quadnav.experiments.nav import _ekf_estimator
    from quadnav.loop import LoopClosure

    rng = np.random.default_rng(0)
    for sets, follows in (([], ()), (["vio.loop=true"], ("vio",))):
        sc = nav_builtin("indoor_vio", sets)
        sensor = build_vio_sensor(sc, rng, rng, 9.81, None)
        assert isinstance(sensor, VioCameraSensor)
        assert isinstance(sensor.vio, LoopClosure) == bool(sets)
        if isinstance(sensor.vio, LoopClosure):
            assert sensor.vio.config.executor == "inline"  # (the same corrections every run)
            sensor.vio.close()
        est = _ekf_estimator(sc, 9.81, 200_000_000)
        assert isinstance(est, AligningNavFilter)
        assert est.setup.ekf.follow_resets == follows


def test_realistic_sensors_give_the_flight_imu_and_a_calibration_off_as_real_ones_are() -> None:
    """``vio.sensors=realistic`` (issue 25, the VIO fused with GPS on sensors as hard as real
    ones): the IMU at the rig's in-flight noise (thesis003_sim's: EuRoC's MAV's vibration, 12
    and 22 times the stated gyro and accelerometer densities) with turn-on biases drawn from the
    rig's spread (PX4's 0.1 rad/s and 0.2 m/s^2), and the VIO given cameras whose calibration is
    off; the renderer keeps the true one. Ideal keeps the stated noise, the true calibration and
    biases of 1e-4 rad/s at most."""
    from quadnav.rig import rig_named

    rig = rig_named("thesis003_sim")
    assert rig.imu is not None and rig.imu.flight_noise is not None
    biases: dict[str, list[float]] = {"ideal": [], "realistic": []}
    for seed in range(20):
        for profile in biases:
            sc = nav_builtin("outdoor_vio_gps", [f"vio.sensors={profile}"])
            rng = np.random.default_rng(seed)
            sensor = build_vio_sensor(sc, rng, np.random.default_rng(seed + 100), 9.81, None)
            assert isinstance(sensor, VioCameraSensor) and sensor.imu is not None
            biases[profile].append(float(np.abs(sensor.imu.bias_g).max()))
            stated = sensor.vio.camera_spec  # type: ignore[attr-defined]
            true = rig.cameras[0]
            moved = float(np.degrees((true.T_B_C.inverse() @ stated.T_B_C).R_A_B.magnitude()))
            focal = stated.camera.K[0, 0] / true.camera.K[0, 0] - 1.0
            sigma = sensor.imu.errors.sg
            if profile == "ideal":
                assert moved == 0.0 and focal == 0.0
                assert sigma == pytest.approx(rig.imu.noise.gyro_noise_density * np.sqrt(200))
            else:
                assert 0.0 < moved < 2.5 and 0.0 < abs(focal) < 0.03
                flight = rig.imu.flight_noise.gyro_noise_density
                assert sigma == pytest.approx(flight * np.sqrt(200))
    assert max(biases["ideal"]) < 1e-3
    # the largest of three axes of a 0.1 rad/s spread: over 20 draws its median is near 0.1
    assert 0.05 < float(np.median(biases["realistic"])) < 0.3
    with pytest.raises(ConfigError, match=r"vio\.sensors is a setting of the VIO"):
        nav_builtin("outdoor_vio_gps_odometry", ["vio.sensors=realistic"])


@pytest.mark.parametrize(
    "scenario", ["outdoor_vio_gps", "outdoor_vio_gps_realistic", "indoor_slam", "indoor_vio"]
)
def test_a_built_in_turned_to_the_absolute_mode_drops_its_own_relative_settings(
    scenario: str,
) -> None:
    """A scenario that sets its VIO frame's drift rates (a setting of the relative mode) can be
    flown in the absolute mode with one --set: its own rates are left out, the mode's defaults
    taken. The caller's own relative settings with the absolute mode are still refused."""
    sc = nav_builtin(scenario, ["vio.odometry_mode=absolute"])
    for spelt in ('vio.odometry_mode="absolute"', "vio.odometry_mode = absolute"):  # (a sweep's)
        assert nav_builtin(scenario, [spelt]).vio == sc.vio
    default = NavScenario().vio
    assert sc.vio.odometry_mode == "absolute"
    assert sc.vio.frame_drift_m_sqrt_s == default.frame_drift_m_sqrt_s
    assert sc.vio.frame_drift_from_covariance == default.frame_drift_from_covariance
    assert nav_builtin(scenario).vio.odometry_mode == "relative"  # (as built, untouched)
    with pytest.raises(ConfigError, match=r"vio\.frame_drift_yaw_rad_sqrt_s is a setting of"):
        nav_builtin(scenario, ["vio.odometry_mode=absolute", "vio.frame_drift_yaw_rad_sqrt_s=0.01"])
