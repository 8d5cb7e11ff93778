from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from quadnav.errors import ConfigError
from quadnav.experiments import PlanarConfig
from quadnav.io import apply_override, dump_config, load_config


def test_no_file_no_overrides_gives_the_thesis_defaults() -> None:
    c = load_config(PlanarConfig)
    assert (c.dt_s, c.duration_s) == (0.01, 10.0)
    assert (c.imu.accel_sigma_m_s2, c.imu.gyro_sigma_rad_s) == (0.25, 0.03)
    assert (c.gps.sigma_m, c.gps.delay_s, c.gps.period_s) == (0.01, 1.0, 0.3)


def test_file_and_overrides_combine(tmp_path: Path) -> None:
    f = tmp_path / "c.yaml"
    f.write_text("gps:\n  delay_s: 0.5\nseeds: 3\n")
    c = load_config(
        PlanarConfig,
        f,
        ["gps.period_s=0.1", "imu.accel_model=kinematic", "estimator.gate_probability=null"],
    )
    assert c.gps.delay_s == 0.5 and c.gps.period_s == 0.1 and c.seeds == 3
    assert c.imu.accel_model == "kinematic" and c.estimator.gate_probability is None


def test_resolved_config_round_trips(tmp_path: Path) -> None:
    c = load_config(PlanarConfig, None, ["gps.delay_s=0.25", "experiments=[handled]"])
    f = tmp_path / "resolved.yaml"
    f.write_text(dump_config(c))
    assert load_config(PlanarConfig, f) == c


@pytest.mark.parametrize(
    ("overrides", "names"),
    [
        (["gps.delay_s=-1"], "gps.delay_s"),
        (["gps.period_s=0.001"], "gps.period_s"),
        (["gps.bogus=1"], "gps.bogus: unknown key"),
        (["colour=red"], "colour: unknown key"),
        (["dt_s=abc"], "dt_s"),
        (["imu.accel_model=magic"], "imu.accel_model"),
        (["experiments=[handled, nonsense]"], "experiments.1"),
        (["estimator.gate_probability=1.5"], "estimator.gate_probability"),
        (["controller.kd_tilt=-0.1"], "controller.kd_tilt"),
        (["duration_s=0.001"], "duration_s"),
    ],
)
def test_bad_values_are_one_line_errors_naming_the_key(overrides: list[str], names: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(PlanarConfig, None, overrides)
    message = str(info.value)
    assert names in message
    assert "\n" not in message


def test_file_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        load_config(PlanarConfig, tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("gps:\n  delay_s: [1, 2\nseeds: 3\n")
    with pytest.raises(ConfigError, match="line"):
        load_config(PlanarConfig, bad)
    listy = tmp_path / "list.yaml"
    listy.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="mapping"):
        load_config(PlanarConfig, listy)
    binary = tmp_path / "bin.yaml"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(ConfigError):
        load_config(PlanarConfig, binary)
    with pytest.raises(ConfigError, match="not a file"):
        load_config(PlanarConfig, tmp_path)


@pytest.mark.parametrize("bad", ["novalue", "=3", "a..b=1", ".a=1"])
def test_malformed_overrides(bad: str) -> None:
    with pytest.raises(ConfigError, match=r"key\.subkey=value"):
        apply_override({}, bad)


def test_override_into_a_value_is_refused() -> None:
    with pytest.raises(ConfigError, match="not a section"):
        apply_override({"seeds": 3}, "seeds.x=1")


@given(st.lists(st.text(max_size=30), max_size=4))
def test_garbage_overrides_never_crash(overrides: list[str]) -> None:
    """Any override list either validates or raises ConfigError, never anything else."""
    try:
        c = load_config(PlanarConfig, None, overrides)
    except ConfigError as exc:
        assert "\n" not in str(exc)
    else:
        assert isinstance(c, PlanarConfig)
        yaml.safe_load(dump_config(c))


def test_overrides_leave_the_base_mapping_as_it_was() -> None:
    """An override of a nested key on a built-in scenario does not leak into the next load
    (the base's sections were shared, and the first --set wrote into the built-in table)."""
    from quadnav.experiments.flight import FlightConfig, builtin_config

    base = builtin_config("circle_gusts")
    gusty = load_config(FlightConfig, None, ["wind.gust_sigma_m_s=5"], base=base)
    assert gusty.wind.gust_sigma_m_s == 5.0
    assert base["wind"] == {"gust_sigma_m_s": 2.0, "gust_tau_s": 2.0}
    again = load_config(FlightConfig, None, [], base=builtin_config("circle_gusts"))
    assert again.wind.gust_sigma_m_s == 2.0
