"""The sweep's grid: values from their specs, and every refusal before anything runs names the
option (no flight is flown here)."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav.errors import ConfigError
from quadnav.experiments.sweep import plan_sweep, sweep_spec
from quadnav.experiments.sweep_grid import (
    MAX_AXIS_COUNT,
    check_sweep_size,
    grid_axis,
    parse_grid_option,
    sweep_seeds,
)


def test_a_range_is_count_values_with_both_ends() -> None:
    axis = parse_grid_option("vision.delay_s=0.05:0.5:10")
    assert axis.key == "vision.delay_s"
    np.testing.assert_allclose(axis.values, [0.05 + 0.05 * k for k in range(10)], rtol=1e-12)
    assert axis.values[0] == 0.05 and axis.values[-1] == 0.5
    down = parse_grid_option("plan.height_m = 2:1:3".replace(" ", ""))
    assert down.values == (2.0, 1.5, 1.0)


def test_whole_ends_give_integers_lists_and_words_are_read_as_yaml() -> None:
    assert parse_grid_option("vision.marker_grid=3:9:4").values == (3, 5, 7, 9)
    assert all(type(v) is int for v in parse_grid_option("vision.marker_grid=3:9:4").values)
    assert parse_grid_option("vision.source=[camera,pose]").values == ("camera", "pose")
    assert parse_grid_option("vision.delay_s=0.1").values == (0.1,)
    lists = parse_grid_option("vision.dropouts_s=[[],[[2,3]]]")
    assert lists.values == ([], [[2, 3]])
    # a sweep file's values are taken as they are; its text may be a range
    assert grid_axis("vision.delay_s", [0.1, 0.2], from_text=False).values == (0.1, 0.2)
    assert grid_axis("vision.delay_s", "0:1:3", from_text=False).values == (0.0, 0.5, 1.0)


@pytest.mark.parametrize(
    ("text", "named", "why"),
    [
        ("vision.delay_s=0:1", "--grid vision.delay_s=0:1", "start:stop:count"),
        ("vision.delay_s=0:1:0", "--grid vision.delay_s", "count must be"),
        (f"vision.delay_s=0:1:{MAX_AXIS_COUNT + 1}", "--grid vision.delay_s", "count must be"),
        ("vision.delay_s=0:1:99999999999999", "--grid vision.delay_s", "count must be"),
        ("vision.delay_s=0:1:1", "--grid vision.delay_s", "count >= 2"),
        ("vision.delay_s=[]", "--grid vision.delay_s", "empty"),
        ("vision.delay_s=[0.1,0.1]", "--grid vision.delay_s", "twice"),
        ("vision.delay_s=[0.1", "--grid vision.delay_s", "not a value"),
        ("seed=[1,2]", "--grid seed", "--seeds"),
        ("vision.delay_s", "--grid vision.delay_s", "KEY=SPEC"),
        ("=1", "--grid =1", "KEY=SPEC"),
    ],
)
def test_a_bad_grid_is_one_line_naming_the_option(text: str, named: str, why: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_grid_option(text)
    msg = str(info.value)
    assert msg.startswith(named) and why in msg and "\n" not in msg, msg


def test_an_absurd_sweep_is_refused_from_its_size_alone() -> None:
    big = parse_grid_option(f"vision.delay_s=0:1:{MAX_AXIS_COUNT}")
    other = parse_grid_option(f"vision.sigma_m=0.01:0.1:{MAX_AXIS_COUNT}")
    with pytest.raises(ConfigError, match=r"^--grid: 1,000,000 grid points"):
        check_sweep_size([big, other], 1)
    small = parse_grid_option("vision.sigma_m=0.01:0.1:10")
    assert check_sweep_size([big, small], 100) == 1_000_000  # at the bound: allowed
    with pytest.raises(ConfigError, match=r"^--seeds: 10,000 grid points x 101 seeds"):
        check_sweep_size([big, small], 101)
    with pytest.raises(ConfigError, match=r"^--grid vision.sigma_m: given twice"):
        check_sweep_size([small, small], 1)


def test_seeds_are_a_count_or_a_list() -> None:
    assert sweep_seeds("3", first=5) == (5, 6, 7)
    assert sweep_seeds("0-4", first=5) == (0, 1, 2, 3, 4)
    assert sweep_seeds("2,7", first=0) == (2, 7)
    for bad in ("0", "100000", "4-2", "x"):
        with pytest.raises(ConfigError, match=r"^--seeds"):
            sweep_seeds(bad, first=0)


def _plan(
    grid: list[str], overrides: list[str] | None = None, scenario: str = "indoor_vision_pose"
) -> None:
    plan_sweep(sweep_spec(None, scenario, grid, "2", overrides or []))


def test_an_unknown_key_or_a_bad_value_names_the_grid_option() -> None:
    with pytest.raises(ConfigError) as info:
        _plan(["vision.delay_s=[0.1,0.2]", "vision.delay=[1,2]"])
    assert str(info.value).startswith("--grid vision.delay=1:") and "unknown key" in str(info.value)
    with pytest.raises(ConfigError) as info:
        _plan(["vision.delay_s=[0.1,-1]"])  # a delay is at least 0
    assert str(info.value).startswith("--grid vision.delay_s=-1:")
    with pytest.raises(ConfigError, match=r"^SCENARIO .no_such_scenario.: neither"):
        _plan(["vision.delay_s=0.1"], scenario="no_such_scenario")
    with pytest.raises(ConfigError, match=r"^--grid: give at least one"):
        _plan([])


def test_each_grid_point_is_validated_whole_before_anything_runs() -> None:
    """Each value is valid with the others' defaults; one combination is not (an IMU too slow
    for the time the filter levels on the ground): the point is named."""
    grid = ["imu.rate_hz=[0.4,250]", "estimator.align_s=[5,1]"]
    with pytest.raises(ConfigError) as info:
        _plan(grid, ["estimator.align_s=5"])
    msg = str(info.value)
    assert msg.startswith("--grid point imu.rate_hz=0.4, estimator.align_s=1:"), msg
    _plan(["imu.rate_hz=[0.4,250]", "estimator.align_s=[5,3]"], ["estimator.align_s=5"])
