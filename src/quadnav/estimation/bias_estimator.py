"""A one-state bias estimator beside the main filter, as PX4 EKF2's ``BiasEstimator``
(``bias_estimator.cpp``): the offset of a height sensor (barometer) from the filter's height.

The bias is a random walk (process noise spectral density ``nsd``, its variance capped at
``var_max``); each reading observes ``reading - filter height`` with the reading's variance
plus the filter's height variance, gated at ``gate`` standard deviations. The main filter
fuses ``reading - bias`` with the reading's variance plus the bias variance. PX4's
innovation-sequence offset detection (a 1000x process-noise boost) is not modelled.
"""

from __future__ import annotations

from dataclasses import dataclass

from quadnav.estimation.horizon import require_positive

__all__ = ["BiasEstimator"]


@dataclass(slots=True)
class BiasEstimator:
    """The bias, its variance and how it may move (``nsd`` in units per second per sqrt(Hz))."""

    nsd: float
    bias: float = 0.0
    var: float = 0.1  # PX4's initial state variance
    var_max: float = 2.0
    gate: float = 3.0
    n_fused: int = 0
    n_rejected: int = 0

    def __post_init__(self) -> None:
        require_positive(self, ("nsd", "var", "var_max", "gate"))

    def predict(self, dt_s: float) -> None:
        self.var = min(max(self.var + self.nsd**2 * dt_s, 1e-8), self.var_max)

    def fuse(self, measurement: float, measurement_var: float) -> bool:
        """One observation of the bias; False if it fell outside the gate (not fused)."""
        s = self.var + max(1e-4, measurement_var)
        innov = measurement - self.bias
        if innov * innov / (self.gate**2 * s) > 1.0:
            self.n_rejected += 1
            return False
        k = self.var / s
        self.bias += k * innov
        self.var = max(self.var * (1.0 - k), 1e-8)
        self.n_fused += 1
        return True
