"""The generated reference pages say what the code does: every configuration key as ``--set``
takes it, with its default; every model under a command; units read from the names."""

from __future__ import annotations

import math
from typing import Any

import pytest
import yaml

from quadnav.io.config import load_config
from tests.docs.test_docs import _reference

ref = _reference()


@pytest.mark.parametrize(
    ("name", "unit"),
    [
        ("delay_s", "s"),
        ("rate_hz", "Hz"),
        ("marker_length_m", "m"),
        ("frame_yaw_deg", "deg"),
        ("pixel_sigma_px", "px"),
        ("accel_m_s2", "m/s²"),
        ("gyro_noise_rad_s", "rad/s"),
        ("accel_bias_noise_m_s3", "m/s³"),
        ("drift_m_sqrt_s", "m/√s"),
        ("frame_drift_yaw_rad_sqrt_s", "rad/√s"),
        ("gyro_bias_rw_rad_s_sqrt_s", "rad/s/√s"),
        ("inertia_kg_m2", "kg·m²"),
        ("seeds", ""),
        ("squares_x", ""),
        ("gate_sigma", ""),
    ],
)
def test_the_unit_is_read_from_the_name(name: str, unit: str) -> None:
    assert ref.unit_of(name) == unit


def test_every_config_model_is_documented_under_a_command() -> None:
    assert ref.unreached_models() == set(), "add the command's root model to CONFIG_ROOTS"


def _get(model: Any, key: str) -> Any:
    for part in key.split("."):
        model = getattr(model, part)
    return model


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        return bool(math.isclose(float(a), float(b), rel_tol=1e-5, abs_tol=1e-12))
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return bool(a == b)


#: what a command gives its model that has no default (the sequence's world: its first argument)
REQUIRED: dict[str, dict[str, Any]] = {"quadnav dataset make": {"world": "room"}}


@pytest.mark.parametrize("root", ref.CONFIG_ROOTS, ids=lambda r: r[0])
def test_every_documented_key_and_default_is_what_set_takes(root: tuple[str, str, str]) -> None:
    """Each key, set with ``--set key=<the documented default>``, validates and gives the
    model's own default: the keys are the dotted keys --set takes, the defaults are right."""
    model = ref.root_model(root[1])
    base = REQUIRED.get(root[0], {})
    default = model.model_validate(base)
    keys = [k for k in ref.config_keys(model) if "[]" not in k.key and k.default != "required"]
    assert len(keys) > 3
    for k in keys:
        text = k.default.strip("`")
        overridden = load_config(model, None, [f"{k.key}={text}"], base=dict(base))
        expected = _get(default, k.key)
        got = _get(overridden, k.key)
        if hasattr(expected, "model_dump"):
            expected, got = expected.model_dump(), got.model_dump()
        assert _same(got, expected), f"{k.key}: documented default {text!r} reads as {got!r}"


def test_the_configuration_page_states_a_known_key() -> None:
    """One row read as a user would: the run's GPS delay (the README's 200 ms late fixes,
    bounded by the 10 s of config_model.MAX_DELAY_S)."""
    page = ref.configuration_page()
    row = next(line for line in page.splitlines() if line.startswith("| `gps.delay_s` |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells == ["`gps.delay_s`", "float", "s", "`0.2`", "≥ 0, ≤ 10", cells[5]]
    assert yaml.safe_load(cells[3].strip("`")) == 0.2


def test_a_config_model_made_outside_quadnav_is_not_asked_for() -> None:
    """A test module's own ConfigModel (tests/experiments/test_vio_run.py has one) made in the
    same worker once failed the check above, depending on the order of the tests."""
    from quadnav.config_model import ConfigModel

    class _Elsewhere(ConfigModel):
        x: int = 1

    assert _Elsewhere not in ref.all_config_models()
    assert ref.unreached_models() == set()
