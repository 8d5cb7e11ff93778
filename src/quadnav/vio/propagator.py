"""The IMU side of the VIO, reusable by any estimator that keeps keyframe states (the GPS
fusion, the SLAM): a buffer of samples in time order, the preintegration from a state's time
to any later time (GTSAM's ``PreintegratedCombinedMeasurements``, midpoint readings: see
:func:`~quadnav.vio.preintegration.preintegrate`), the running propagation of the newest state
at the IMU's rate, and the prediction of a state with its covariance grown by the
preintegration's.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from quadnav.geometry.rotations import so3_exp
from quadnav.messages import ImuSample
from quadnav.units import NS_PER_S
from quadnav.vio.preintegration import preintegrate

__all__ = ["ImuPropagator", "Prediction"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Prediction:
    """A state carried forward by the IMU: pose, world velocity, and their covariances (pose
    in GTSAM's tangent order, rotation then translation)."""

    pose: gtsam.Pose3
    velocity: FloatArray
    cov_pose: FloatArray
    cov_v: FloatArray


class ImuPropagator:
    """IMU samples and the propagation of a state (see the module)."""

    def __init__(self, params: gtsam.PreintegrationCombinedParams) -> None:
        self.params = params
        self.samples: list[ImuSample] = []
        self._t: list[int] = []
        self._running: gtsam.PreintegratedCombinedMeasurements | None = None
        self._from_ns = 0

    @property
    def last_t_ns(self) -> int | None:
        return self._t[-1] if self._t else None

    def push(self, sample: ImuSample) -> None:
        """A sample (in time order: the caller checks), and the running propagation, if any,
        carried to it."""
        prev = self.samples[-1] if self.samples else None
        self.samples.append(sample)
        self._t.append(sample.t_ns)
        run = self._running
        if run is None or prev is None:
            return
        a, b = max(prev.t_ns, self._from_ns), sample.t_ns
        if b > a:  # the reading at the piece's midpoint, as a span from scratch takes it
            u = (0.5 * (a + b) - prev.t_ns) / (b - prev.t_ns)
            acc0, gyro0 = np.asarray(prev.accel_m_s2), np.asarray(prev.gyro_rad_s)
            acc = acc0 + u * (np.asarray(sample.accel_m_s2) - acc0)
            gyro = gyro0 + u * (np.asarray(sample.gyro_rad_s) - gyro0)
            run.integrateMeasurement(acc, gyro, (b - a) / NS_PER_S)

    def span(
        self, t0_ns: int, t1_ns: int, bias: gtsam.imuBias.ConstantBias, *, hold_ns: int = 0
    ) -> gtsam.PreintegratedCombinedMeasurements:
        """The IMU from ``t0_ns`` to ``t1_ns`` with ``bias`` (empty for no span); ``hold_ns``:
        how far past the newest sample the last one may hold. A ``VioError`` when the buffer
        does not cover the span."""
        if t1_ns <= t0_ns:
            return gtsam.PreintegratedCombinedMeasurements(self.params, bias)
        i = max(bisect.bisect_right(self._t, t0_ns) - 1, 0)
        return preintegrate(self.params, self.samples[i:], t0_ns, t1_ns, bias, hold_ns=hold_ns)

    def gyro_rotation(
        self, t0_ns: int, t1_ns: int, gyro_bias: FloatArray, *, hold_ns: int = 0
    ) -> FloatArray | None:
        """The body's rotation from ``t0_ns`` to ``t1_ns`` (R_B0_B1) by the gyro alone, its
        bias taken off: readings interpolated to the middle of each piece between samples and
        summed into one rotation vector (to first order, enough for a prediction). None when
        the buffer does not cover the span (the newest sample may hold ``hold_ns`` past it)."""
        t = self._t
        i = bisect.bisect_right(t, t0_ns) - 1
        if i < 0 or t1_ns <= t0_ns or t[-1] + hold_ns < t1_ns:
            return None
        j = bisect.bisect_left(t, t1_ns, lo=i)
        ts = np.asarray(t[i : j + 1], np.float64)
        g = np.array([s.gyro_rad_s for s in self.samples[i : j + 1]], np.float64)
        if ts[-1] < t1_ns:  # the newest sample holds
            ts, g = np.append(ts, float(t1_ns)), np.vstack([g, g[-1]])
        a, b = np.maximum(ts[:-1], t0_ns), np.minimum(ts[1:], t1_ns)
        u = ((0.5 * (a + b) - ts[:-1]) / (ts[1:] - ts[:-1]))[:, None]
        rates = g[:-1] + u * (g[1:] - g[:-1])
        rotvec = ((b - a)[:, None] * (rates - np.asarray(gyro_bias))).sum(axis=0) / NS_PER_S
        return so3_exp(rotvec)

    def run_from(self, t0_ns: int, bias: gtsam.imuBias.ConstantBias, *, hold_ns: int = 0) -> None:
        """Start the running propagation from a state at ``t0_ns`` (to the newest sample; each
        sample pushed after carries it further)."""
        last = self.last_t_ns
        self._running = self.span(t0_ns, last if last is not None else t0_ns, bias, hold_ns=hold_ns)
        self._from_ns = t0_ns

    def stop(self) -> None:
        self._running = None

    @property
    def running(self) -> gtsam.PreintegratedCombinedMeasurements | None:
        """The running propagation since :meth:`run_from`, None when stopped."""
        return self._running

    @staticmethod
    def predict(
        pose: gtsam.Pose3,
        velocity: FloatArray,
        bias: gtsam.imuBias.ConstantBias,
        pim: gtsam.PreintegratedCombinedMeasurements,
        cov_pose: FloatArray,
        cov_v: FloatArray,
    ) -> Prediction:
        """A state carried by ``pim``; its covariance grown by the preintegration's (rotation,
        position; velocity turned into the world)."""
        nav = pim.predict(gtsam.NavState(pose, velocity), bias)
        Q = np.asarray(pim.preintMeasCov())
        pose_1 = nav.pose()
        R = pose_1.rotation().matrix()
        return Prediction(
            pose=pose_1,
            velocity=np.asarray(nav.velocity(), np.float64),
            cov_pose=cov_pose + Q[0:6, 0:6],
            cov_v=cov_v + R @ Q[6:9, 6:9] @ R.T,
        )

    def prune(self, keep_ns: int) -> None:
        """Forget the samples before ``keep_ns`` (the one at or before it kept), in chunks."""
        i = max(bisect.bisect_right(self._t, keep_ns) - 2, 0)
        if i > 1000:
            del self.samples[:i]
            del self._t[:i]
