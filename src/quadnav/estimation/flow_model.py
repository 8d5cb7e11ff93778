"""PX4's optical-flow observation for the navigation EKF: prediction, Jacobian and noise.

A downward camera at the body origin sees the flat floor (world ``z = floor_z``) along its
optical axis, body -z, at the range ``r = h / R22`` (``h`` the height above the floor,
``R22`` the cosine of the tilt). With the body rotation removed (the flow sensor's own
integrated gyro subtracted), the line-of-sight rate of the centre of the image about the
body x and y axes is (EKF2 ``OpticalFlowSource::predictFlow``, here in FLU)::

    flow = (R22 / h) [ v_B_y, -v_B_x ],    v_B = R_W_B^T v_W

with the sign convention of :class:`~quadnav.messages.FlowSample` (a right-handed rotation
of the sensor gives positive flow; moving forward gives negative flow about y). The height
comes from the state, ``h = max(z - floor_z, min_height)``, as PX4 bounds it from below.

The Jacobian is taken with respect to the 15-element error state of
:data:`~quadnav.estimation.layout.NAV_ERROR` (``R_true = R Exp(dtheta)``): attitude through
both ``v_B`` and ``R22``, velocity, and the height (zero once the height is clamped).

The noise follows the sample's quality as EKF2's ``calcOptFlowMeasVar``: a standard
deviation of ``EKF2_OF_N_MIN`` at quality 255, ``EKF2_OF_N_MAX`` at ``EKF2_OF_QMIN``,
linear in between.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.estimation.layout import NAV_ERROR
from quadnav.messages import FlowSample

__all__ = [
    "FlowPrediction",
    "compensated_flow_rate",
    "flow_noise_sigma",
    "predict_flow",
    "tilt_cosine_jacobian",
]

FloatArray = NDArray[np.float64]
_ATT, _VEL = NAV_ERROR["att"], NAV_ERROR["vel"]
_Z = NAV_ERROR.index("z")
# S v_B = [v_B_y, -v_B_x]: the two flow axes from the body velocity
_S = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])


def tilt_cosine_jacobian(R_W_B: FloatArray) -> FloatArray:
    """``d R22 / d dtheta`` (3,) for ``R Exp(dtheta)``: ``-R[2, :] [e3]x``, the cosine of the
    tilt of the body z axis (a downward range and the flow scale both divide by it)."""
    row = R_W_B[2, :]
    return np.array([-row[1], row[0], 0.0])


@dataclass(frozen=True, slots=True)
class FlowPrediction:
    """The predicted compensated flow rate (rad/s, about body x and y) and its Jacobian
    ``H`` (2 x 15) over the error state; ``height_m`` is the (bounded) height it used and
    ``range_m`` the distance along the optical axis."""

    flow_rate_rad_s: FloatArray
    H: FloatArray
    height_m: float
    range_m: float


def predict_flow(
    R_W_B: FloatArray, v_W: FloatArray, z_m: float, *, floor_z_m: float, min_height_m: float
) -> FlowPrediction:
    """The compensated flow rate of a body at height ``z_m`` over the floor, and its
    Jacobian with respect to the navigation EKF's error state."""
    h_raw = float(z_m) - floor_z_m
    clamped = h_raw < min_height_m
    h = min_height_m if clamped else h_raw
    c = float(R_W_B[2, 2])
    v_B = R_W_B.T @ v_W
    Sv = _S @ v_B
    pred = (c / h) * Sv
    dc = tilt_cosine_jacobian(R_W_B)
    skew_vB = np.array(
        [[0.0, -v_B[2], v_B[1]], [v_B[2], 0.0, -v_B[0]], [-v_B[1], v_B[0], 0.0]]
    )  # d v_B / d dtheta
    H = np.zeros((2, NAV_ERROR.size))
    H[:, _ATT] = (np.outer(Sv, dc) + c * _S @ skew_vB) / h
    H[:, _VEL] = (c / h) * _S @ R_W_B.T
    if not clamped:
        H[:, _Z] = -pred / h
    return FlowPrediction(pred, H, h, h / c)


def compensated_flow_rate(sample: FlowSample, gyro_bias_rad_s: FloatArray) -> FloatArray:
    """The sample's flow rate with the body rotation removed: its own gyro's rate (less that
    gyro's estimated bias) subtracted, as EKF2 does before it compares with the prediction."""
    return np.asarray(
        sample.flow_rate_rad_s - (sample.gyro_rate_rad_s[:2] - gyro_bias_rad_s[:2]),
        dtype=np.float64,
    )


def flow_noise_sigma(
    quality: int, *, quality_min: int, sigma_best_rad_s: float, sigma_worst_rad_s: float
) -> float:
    """EKF2's flow noise (rad/s) for a quality: ``sigma_best`` at 255, ``sigma_worst`` at
    ``quality_min`` and below, linear in between (each at least 0.05 rad/s, as PX4)."""
    best, worst = max(sigma_best_rad_s, 0.05), max(sigma_worst_rad_s, 0.05)
    span = 255.0 - quality_min
    w = min(max((quality - quality_min) / span, 0.0), 1.0) if span >= 1.0 else 0.0
    return best * w + worst * (1.0 - w)
