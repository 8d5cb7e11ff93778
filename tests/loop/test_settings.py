"""``--loop-set``: loop closure's settings from the command line, nested ones by dotted key, each
read as its field's type and checked as in code; a bad key or value is one line naming it."""

from __future__ import annotations

import pytest

from quadnav.errors import LoopError
from quadnav.loop import LoopConfig
from quadnav.loop.settings import loop_config_with, loop_settings


def test_top_level_and_nested_settings_are_set_and_the_rest_kept() -> None:
    got = loop_config_with([
        "max_drift_m=0.5", "graph.loop_sigma_m=0.05", "detector.temporal_consistency=3",
        "verification.min_inliers=30", "executor=thread", "max_drift_m=0.7",
    ])  # fmt: skip
    assert got.max_drift_m == 0.7  # the last of two wins
    assert got.graph.loop_sigma_m == 0.05 and got.detector.temporal_consistency == 3
    assert got.verification.min_inliers == 30 and got.executor == "thread"
    default = LoopConfig()
    assert got.graph.sequential_sigma_m == default.graph.sequential_sigma_m
    assert got.detector.min_normalised_score == default.detector.min_normalised_score
    assert isinstance(got.detector.temporal_consistency, int)


def test_every_setting_is_listed_by_its_dotted_key() -> None:
    keys = loop_settings()
    assert "graph.loop_sigma_m" in keys and "detector.temporal_consistency" in keys
    assert "graph" not in keys  # a nested section is listed by its fields
    for key in ("relocalize_max_jump_m", "graph.loop_sigma_yaw_rad", "verification.ratio"):
        value = keys[key]
        assert loop_config_with([f"{key}={value * 0.5}"]) != LoopConfig()


@pytest.mark.parametrize(
    ("item", "says"),
    [
        ("nope=1", "--loop-set nope: unknown key"),
        ("graph=1", "--loop-set graph: give one of its fields"),
        ("graph.nope=1", "--loop-set graph.nope: unknown key"),
        ("max_drift_m=abc", "not a finite float"),
        ("max_drift_m=inf", "not a finite float"),
        ("detector.temporal_consistency=2.5", "not a finite int"),
        ("max_drift_m=-1", "--loop-set max_drift_m: LoopConfig.max_drift_fraction"),
        ("detector.temporal_consistency=0", "temporal_consistency must be an integer >= 1"),
        ("executor=gpu", "executor must be process, thread or inline"),
        ("max_drift_m", "give KEY=VALUE"),
    ],
)
def test_a_bad_setting_is_one_line_naming_it(item: str, says: str) -> None:
    with pytest.raises(LoopError) as exc:
        loop_config_with([item])
    assert says in str(exc.value) and "\n" not in str(exc.value)
