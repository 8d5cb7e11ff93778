"""Failure detection (VINS-Mono's ``failureDetection``, thesis 003): too few features tracked,
an implausible bias, speed or jump of the solved state against the IMU's prediction, a solve
that did not go through. Each gives the reason a :class:`OdometryEvent` reports; the estimator then
resets and re-initialises."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from quadnav.messages import ImuSample
from quadnav.vio.config import VioConfig

__all__ = ["InputLog", "SolvedState", "state_failure", "tracking_failure"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class SolvedState:
    """The newest keyframe after a solve, next to the IMU's prediction of it."""

    p_W: FloatArray
    v_W: FloatArray
    p_pred_W: FloatArray
    v_pred_W: FloatArray
    accel_bias: FloatArray
    gyro_bias: FloatArray
    accel_bias_before: FloatArray | None = None
    gyro_bias_before: FloatArray | None = None


def tracking_failure(n_features: int, config: VioConfig) -> str | None:
    if n_features < config.fail_min_tracked:
        return f"too few features tracked ({n_features} < {config.fail_min_tracked})"
    return None


def accel_bias_jump_limit(bias_before: FloatArray, config: VioConfig) -> float:
    """How far the accelerometer bias may move in one keyframe: ``fail_max_accel_bias_jump_m_s2``;
    but while its estimate is still near where the start put it (under that limit from zero),
    as far as the start's prior allows a bias to be (three sigmas of ``init_accel_bias_sigma_m_s2``
    per axis), since it is converging onto it. (A realistic IMU drew 0.68 m/s^2 on V1_02 seed 4:
    the first solves moved the bias by 0.6 and the VIO failed twice in its first 2 s.)"""
    limit = config.fail_max_accel_bias_jump_m_s2
    if float(np.linalg.norm(bias_before)) < limit:
        return max(limit, 3.0 * math.sqrt(3.0) * config.init_accel_bias_sigma_m_s2)
    return limit


def state_failure(s: SolvedState, config: VioConfig) -> str | None:
    """The first implausible thing about a solved state, or None."""
    checks: tuple[tuple[float, float, str], ...] = (
        (float(np.linalg.norm(s.accel_bias)), config.fail_max_accel_bias_m_s2, "accel bias m/s^2"),
        (float(np.linalg.norm(s.gyro_bias)), config.fail_max_gyro_bias_rad_s, "gyro bias rad/s"),
        (float(np.linalg.norm(s.v_W)), config.fail_max_speed_m_s, "speed m/s"),
        (
            float(np.linalg.norm(s.v_W - s.v_pred_W)),
            config.fail_max_velocity_jump_m_s,
            "velocity jump m/s",
        ),
        (
            float(np.linalg.norm(s.p_W - s.p_pred_W)),
            config.fail_max_position_jump_m,
            "position jump m",
        ),
    )
    if s.accel_bias_before is not None and s.gyro_bias_before is not None:
        checks += (
            (
                float(np.linalg.norm(s.accel_bias - s.accel_bias_before)),
                accel_bias_jump_limit(s.accel_bias_before, config),
                "accel bias jump m/s^2",
            ),
            (
                float(np.linalg.norm(s.gyro_bias - s.gyro_bias_before)),
                config.fail_max_gyro_bias_jump_rad_s,
                "gyro bias jump rad/s",
            ),
        )
    for value, limit, what in checks:
        if not np.isfinite(value) or value > limit:
            return f"implausible {what}: {value:.3g} > {limit:g}"
    return None


@dataclass(slots=True)
class InputLog:
    """Rejected input by kind (``imu_nonfinite``, ``imu_time``, ``image_time``, ``image``...)."""

    counts: Counter[str] = field(default_factory=Counter)
    last_imu_t_ns: int | None = None
    last_image_t_ns: int | None = None

    def imu_ok(self, s: object) -> bool:
        if not isinstance(s, ImuSample):
            self.counts["imu_type"] += 1
            return False
        g, a = np.asarray(s.gyro_rad_s), np.asarray(s.accel_m_s2)
        if (
            g.shape != (3,)
            or a.shape != (3,)
            or not (np.isfinite(g).all() and np.isfinite(a).all())
        ):
            self.counts["imu_nonfinite"] += 1
            return False
        if self.last_imu_t_ns is not None and s.t_ns <= self.last_imu_t_ns:
            self.counts["imu_time"] += 1
            return False
        self.last_imu_t_ns = s.t_ns
        return True

    def image_time_ok(self, t_ns: object) -> bool:
        if isinstance(t_ns, bool) or not isinstance(t_ns, int | np.integer):
            self.counts["image_time"] += 1
            return False
        if self.last_image_t_ns is not None and int(t_ns) <= self.last_image_t_ns:
            self.counts["image_time"] += 1
            return False
        self.last_image_t_ns = int(t_ns)
        return True

    @property
    def total(self) -> int:
        return sum(self.counts.values())
