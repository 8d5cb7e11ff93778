"""Planar trajectories and the summary and plot over seeds of the planar study (thesis 000,
figures 2.3-2.5), over arrays and per-seed metrics; the study itself is
:mod:`quadnav.experiments.planar_study`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from numpy.typing import NDArray

from quadnav.eval.na import median_or_na
from quadnav.geometry.trajectory import Trajectory

__all__ = [
    "SUMMARY_KEYS",
    "planar_trajectory",
    "plot_monte_carlo",
    "summarize_seeds",
]

FloatArray = NDArray[np.float64]

#: Per-seed metrics that the summary reports as a median over seeds.
SUMMARY_KEYS = (
    "rmse_delayed_m",
    "rmse_output_m",
    "rmse_floor_m",
    "output_over_floor",
    "nees_mean",
)


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


def summarize_seeds(per_seed: list[dict[str, Any]]) -> dict[str, Any]:
    """Median, mean, 10th and 90th percentile over seeds of each summary metric."""
    out: dict[str, Any] = {"seeds": len(per_seed)}
    for key in SUMMARY_KEYS:
        values = [m[key] for m in per_seed]
        finite = np.array([v for v in values if not isinstance(v, str)], dtype=np.float64)
        finite = finite[np.isfinite(finite)]
        if len(finite) == 0:
            why = median_or_na(values)  # no seed has a number: the reason
            out[key] = {"median": why, "mean": why, "p10": why, "p90": why}
            continue
        out[key] = {
            "median": float(np.median(finite)),
            "mean": float(np.mean(finite)),
            "p10": float(np.percentile(finite, 10)),
            "p90": float(np.percentile(finite, 90)),
        }
    for key in ("gps_received", "gps_fused", "gps_rejected_gate", "gps_rejected_too_old"):
        out[f"{key}_total"] = int(sum(m[key] for m in per_seed))
    return out


def plot_monte_carlo(per_experiment: dict[str, list[dict[str, Any]]], path: Path) -> None:
    """Distribution over seeds of each estimate's position RMSE, per experiment (log scale)."""
    fig, ax = plt.subplots(figsize=(10, 5), constrained_layout=True)
    labels, data = [], []
    for exp, per_seed in per_experiment.items():
        for key, name in (
            ("rmse_delayed_m", "delayed"),
            ("rmse_output_m", "output"),
            ("rmse_floor_m", "floor"),
        ):
            if exp != "handled" and name != "delayed":
                continue
            labels.append(f"{exp}\n{name}")
            data.append([m[key] for m in per_seed])
    ax.boxplot(data, tick_labels=labels)
    ax.set_yscale("log")
    ax.set_ylabel("position RMSE (m)")
    ax.set_title(f"Monte Carlo over {len(next(iter(per_experiment.values())))} seeds")
    ax.grid(True, which="both", alpha=0.3)
    fig.savefig(path, dpi=100)
    plt.close(fig)
