"""Planar trajectories and the summary and plot over seeds of the planar study (thesis 000,
figures 2.3-2.5), over arrays and per-seed metrics; the study itself is
:mod:`quadnav.experiments.planar_study`."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from numpy.typing import NDArray

from quadnav.eval.na import Metric, median_or_na
from quadnav.geometry.trajectory import Trajectory

__all__ = [
    "PlanarMetrics",
    "PlanarSummary",
    "SeedSpread",
    "planar_trajectory",
    "plot_monte_carlo",
    "summarize_seeds",
]

FloatArray = NDArray[np.float64]
Name = TypeVar("Name", bound=str)  # an experiment's name


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanarMetrics:
    """One planar run's metrics: position RMSE of each estimate against the truth at its own
    horizon (delayed: at the delayed horizon; output and floor: now), the NEES of the 5-state
    delayed estimate and the GPS counters."""

    seed: int
    rmse_delayed_m: Metric
    rmse_output_m: Metric
    rmse_floor_m: Metric
    output_over_floor: Metric
    nees_mean: Metric
    nees_steps: int
    gps_received: int
    gps_fused: int
    gps_rejected_gate: int
    gps_rejected_too_old: int
    gps_pending_at_end: int
    imu_buffer_length: int


@dataclass(frozen=True, slots=True, kw_only=True)
class SeedSpread:
    """A metric over seeds: median, mean, 10th and 90th percentile of the seeds that have a
    number (each the first seed's reason when none has)."""

    median: Metric
    mean: Metric
    p10: Metric
    p90: Metric


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanarSummary:
    """One experiment over its seeds: the spread of each RMSE, the ratio and the NEES; the GPS
    counters summed."""

    seeds: int
    rmse_delayed_m: SeedSpread
    rmse_output_m: SeedSpread
    rmse_floor_m: SeedSpread
    output_over_floor: SeedSpread
    nees_mean: SeedSpread
    gps_received_total: int
    gps_fused_total: int
    gps_rejected_gate_total: int
    gps_rejected_too_old_total: int


def planar_trajectory(
    t_ns: NDArray[np.int64], p_xz: FloatArray, theta: FloatArray, name: str = ""
) -> Trajectory:
    """A planar state history as a 3-D trajectory (y = 0, pitch about +y)."""
    n = len(t_ns)
    zeros = np.zeros(n)
    return Trajectory(
        t_ns=t_ns,
        p_W_B=np.column_stack([p_xz[:, 0], zeros, p_xz[:, 1]]),
        q_W_B_xyzw=np.column_stack([zeros, np.sin(theta / 2), zeros, np.cos(theta / 2)]),
        name=name,
    )


def _spread(values: Sequence[Metric]) -> SeedSpread:
    finite = np.array([v for v in values if not isinstance(v, str)], dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    if len(finite) == 0:
        why = median_or_na(values)  # no seed has a number: the reason
        return SeedSpread(median=why, mean=why, p10=why, p90=why)
    return SeedSpread(
        median=float(np.median(finite)),
        mean=float(np.mean(finite)),
        p10=float(np.percentile(finite, 10)),
        p90=float(np.percentile(finite, 90)),
    )


def summarize_seeds(per_seed: Sequence[PlanarMetrics]) -> PlanarSummary:
    """Each metric's spread over seeds, and the GPS counters summed."""
    return PlanarSummary(
        seeds=len(per_seed),
        rmse_delayed_m=_spread([m.rmse_delayed_m for m in per_seed]),
        rmse_output_m=_spread([m.rmse_output_m for m in per_seed]),
        rmse_floor_m=_spread([m.rmse_floor_m for m in per_seed]),
        output_over_floor=_spread([m.output_over_floor for m in per_seed]),
        nees_mean=_spread([m.nees_mean for m in per_seed]),
        gps_received_total=sum(m.gps_received for m in per_seed),
        gps_fused_total=sum(m.gps_fused for m in per_seed),
        gps_rejected_gate_total=sum(m.gps_rejected_gate for m in per_seed),
        gps_rejected_too_old_total=sum(m.gps_rejected_too_old for m in per_seed),
    )


def plot_monte_carlo(per_experiment: Mapping[Name, Sequence[PlanarMetrics]], path: Path) -> None:
    """Distribution over seeds of each estimate's position RMSE, per experiment (log scale)."""
    fig, ax = plt.subplots(figsize=(10, 5), constrained_layout=True)
    labels, data = [], []
    for exp, per_seed in per_experiment.items():
        series = [("delayed", [m.rmse_delayed_m for m in per_seed])]
        if exp == "handled":
            series += [
                ("output", [m.rmse_output_m for m in per_seed]),
                ("floor", [m.rmse_floor_m for m in per_seed]),
            ]
        for name, values in series:
            labels.append(f"{exp}\n{name}")
            data.append(values)
    ax.boxplot(data, tick_labels=labels)
    ax.set_yscale("log")
    ax.set_ylabel("position RMSE (m)")
    ax.set_title(f"Monte Carlo over {len(next(iter(per_experiment.values())))} seeds")
    ax.grid(True, which="both", alpha=0.3)
    fig.savefig(path, dpi=100)
    plt.close(fig)
