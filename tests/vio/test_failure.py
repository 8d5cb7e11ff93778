"""Failure detection on solved states: each implausible quantity is named."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav.vio.config import VioConfig
from quadnav.vio.failure import SolvedState, state_failure, tracking_failure


def _state(**kw: np.ndarray) -> SolvedState:
    z = np.zeros(3)
    base = dict(p_W=z, v_W=z, p_pred_W=z, v_pred_W=z, accel_bias=z, gyro_bias=z)
    base.update(kw)
    return SolvedState(**base)


def test_a_plausible_state_passes() -> None:
    s = _state(v_W=np.array([1.0, 0.0, 0.0]), v_pred_W=np.array([0.9, 0.0, 0.0]))
    assert state_failure(s, VioConfig()) is None


@pytest.mark.parametrize(
    ("field", "value", "word"),
    [
        ("accel_bias", np.array([3.0, 0.0, 0.0]), "accel bias"),
        ("gyro_bias", np.array([0.0, 1.5, 0.0]), "gyro bias"),
        ("v_W", np.array([0.0, 0.0, 25.0]), "speed"),
        ("p_W", np.array([2.0, 0.0, 0.0]), "position jump"),
        ("accel_bias", np.array([np.nan, 0.0, 0.0]), "accel bias"),
    ],
)
def test_implausible_states_are_named(field: str, value: np.ndarray, word: str) -> None:
    reason = state_failure(_state(**{field: value}), VioConfig())
    assert reason is not None and word in reason


def test_velocity_jump_against_the_prediction() -> None:
    s = _state(v_W=np.array([4.0, 0.0, 0.0]))
    reason = state_failure(s, VioConfig())
    assert reason is not None and "velocity jump" in reason


def test_bias_jumps_in_one_keyframe() -> None:
    """A jump beyond 0.5 m/s^2 is implausible once the bias has left its start; from near zero
    the bias may still converge onto anything the start's prior allows (1.04 m/s^2 at 0.2 per
    axis): a realistic IMU's 0.68 m/s^2 is not a failure."""
    z = np.zeros(3)
    assert VioConfig().init_accel_bias_sigma_m_s2 == 0.2
    jump_a = _state(accel_bias=np.array([1.2, 0.0, 0.0]), accel_bias_before=z, gyro_bias_before=z)
    converging = _state(accel_bias=np.array([0.0, 0.6, -0.4]), accel_bias_before=z,
                        gyro_bias_before=z)  # fmt: skip
    late = _state(accel_bias=np.array([0.0, 0.6, 0.0]), accel_bias_before=np.array([0, 0, 0.6]),
                  gyro_bias_before=z)  # fmt: skip
    assert state_failure(converging, VioConfig()) is None
    assert "accel bias jump" in (state_failure(late, VioConfig()) or "")
    jump_g = _state(gyro_bias=np.array([0.0, 0.0, 0.2]), accel_bias_before=z, gyro_bias_before=z)
    slow = _state(accel_bias=np.array([0.8, 0.0, 0.0]), accel_bias_before=np.array([0.7, 0, 0]),
                  gyro_bias_before=z)  # fmt: skip
    assert "accel bias jump" in (state_failure(jump_a, VioConfig()) or "")
    assert "gyro bias jump" in (state_failure(jump_g, VioConfig()) or "")
    assert state_failure(slow, VioConfig()) is None


def test_too_few_tracks() -> None:
    assert tracking_failure(3, VioConfig()) is not None
    assert tracking_failure(50, VioConfig()) is None
