"""The output predictor's information floor.

At each step the best any output predictor can do with what it has is to take the delayed
estimate and re-integrate it through the IMU samples buffered since the delayed horizon.
This computes that, vectorised over all steps of a run, as a diagnostic.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import EstimationError
from quadnav.estimation.horizon import Kinematics

__all__ = ["reintegration_floor"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def reintegration_floor(
    kin: Kinematics,
    *,
    pos_d: FloatArray,
    vel_d: FloatArray,
    att_d: FloatArray,
    start_idx: IntArray,
    end_idx: IntArray,
    gyro: FloatArray,
    accel: FloatArray,
    dt_s: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Re-integrate delayed states through buffered IMU samples.

    Row ``k`` starts from the delayed state (``pos_d[k]``...), valid at IMU sample
    ``start_idx[k]``, and integrates IMU samples ``start_idx[k] + 1 .. end_idx[k]`` of the
    run's IMU arrays (``gyro``, ``accel`` (M, 3), ``dt_s`` (M,): the step ending at each sample).
    """
    start = np.asarray(start_idx, dtype=np.int64)
    end = np.asarray(end_idx, dtype=np.int64)
    if np.any(end < start) or (len(end) and (start.min() < 0 or end.max() >= len(dt_s))):
        raise EstimationError(
            "floor indices must satisfy 0 <= start <= end < number of IMU samples"
        )
    pos, vel, att = pos_d.copy(), vel_d.copy(), att_d.copy()
    steps = end - start
    for m in range(1, int(steps.max(initial=0)) + 1):
        active = steps >= m
        j = np.where(active, start + m, 0)
        p_new, v_new, a_new = kin.integrate(pos, vel, att, gyro[j], accel[j], dt_s[j])
        mask = active[:, None]
        pos = np.where(mask, p_new, pos)
        vel = np.where(mask, v_new, vel)
        att = np.where(mask, a_new, att)
    return pos, vel, att
