"""Trajectory figures (PNG): x/y/z against time, 3-D and top views, errors coloured by size.

The same kinds of figure as thesis 003's figures 5.2-5.4. Vectorised; matplotlib's Agg
backend, so nothing needs a screen.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.colors import Normalize
from numpy.typing import NDArray

from quadnav.geometry.trajectory import Trajectory

__all__ = ["MAX_PLOT_POINTS", "plot_errors", "plot_trajectories", "plot_xyz", "thinned"]

FloatArray = NDArray[np.float64]
#: The most points a line of a figure draws (a figure is ~1,400 pixels wide): long trajectories
#: are thinned for drawing, the metrics use every pose; a coloured line keeps a segment object a
#: point, so what a figure costs stays bounded however long the run.
MAX_PLOT_POINTS = 5000


def thinned(n: int) -> slice:
    """Every k-th of ``n`` points, at most :data:`MAX_PLOT_POINTS` of them."""
    return slice(None, None, max(1, -(-n // MAX_PLOT_POINTS)))


def _plane_axes(traj: Trajectory) -> tuple[int, int]:
    """The two axes along which the trajectory spreads most: x-y for ENU flight, x-z for
    camera-frame datasets such as KITTI."""
    spans = np.ptp(traj.p_W_B, axis=0) if len(traj) else np.ones(3)
    a, b = sorted(np.argsort(spans)[-2:].tolist())
    return int(a), int(b)


def _time_axis(traj: Trajectory, t0_ns: int) -> tuple[FloatArray, str]:
    if not traj.timed:
        return traj.t_ns.astype(np.float64), "pose index"
    return np.asarray((traj.t_ns - t0_ns) * 1e-9, dtype=np.float64), "t (s)"


def plot_xyz(ref: Trajectory, ests: list[Trajectory], path: Path) -> None:
    """x, y and z against time for the reference and every estimate."""
    fig, axes = plt.subplots(3, 1, figsize=(12, 8), sharex=True, constrained_layout=True)
    t0 = int(ref.t_ns[0])
    for traj, style in [(ref, "--"), *[(e, "-") for e in ests]]:
        t, label = _time_axis(traj, t0)
        s = thinned(len(traj))
        for k, ax in enumerate(axes):
            ax.plot(t[s], traj.p_W_B[s, k], style, lw=1.2, label=traj.name or "?")
    for k, ax in enumerate(axes):
        ax.set_ylabel(f"{'xyz'[k]} (m)")
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8, loc="best")
    axes[-1].set_xlabel(label)
    fig.suptitle("Position against time (reference dashed)")
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_trajectories(ref: Trajectory, ests: list[Trajectory], path: Path) -> None:
    """The trajectories in 3-D (true proportions) and from above (equal axes)."""
    fig = plt.figure(figsize=(14, 6), constrained_layout=True)
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax2 = fig.add_subplot(1, 2, 2)
    a, b = _plane_axes(ref)
    for traj, style in [(ref, "--"), *[(e, "-") for e in ests]]:
        s = thinned(len(traj))
        p = traj.p_W_B[s]
        ax3.plot(p[:, 0], p[:, 1], p[:, 2], style, lw=1.0, label=traj.name or "?")
        ax2.plot(p[:, a], p[:, b], style, lw=1.0, label=traj.name or "?")
    spans = np.maximum(np.ptp(ref.p_W_B, axis=0), 1e-3 * max(float(np.ptp(ref.p_W_B)), 1e-9))
    ax3.set_box_aspect(tuple(spans.tolist()))
    ax3.set_xlabel("x (m)")
    ax3.set_ylabel("y (m)")
    ax3.set_zlabel("z (m)")
    ax3.set_title("3-D")
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.set_xlabel(f"{'xyz'[a]} (m)")
    ax2.set_ylabel(f"{'xyz'[b]} (m)")
    ax2.set_title(f"Top view ({'xyz'[a]}-{'xyz'[b]})")
    ax2.grid(True, alpha=0.3)
    ax2.legend(fontsize=8)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_errors(
    ref: Trajectory, est: Trajectory, errors: FloatArray, path: Path, *, what: str = "APE (m)"
) -> None:
    """Error against time, and the trajectory from above coloured by the error's size."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(14, 5), constrained_layout=True)
    t, label = _time_axis(est, int(ref.t_ns[0]))
    s = thinned(len(est))
    e = errors[s]
    pts = np.column_stack([t[s], e])
    norm = Normalize(
        float(e.min()), float(e.max()) if e.max() > e.min() else float(e.min()) + 1e-12
    )
    segs = np.stack([pts[:-1], pts[1:]], axis=1)
    lc = LineCollection(list(segs), cmap="viridis", norm=norm, linewidths=1.5)
    lc.set_array(0.5 * (e[:-1] + e[1:]))
    ax1.add_collection(lc)
    ax1.autoscale()
    rmse = float(np.sqrt(np.mean(errors**2)))
    ax1.axhline(rmse, color="tab:red", ls="--", lw=1, label=f"rmse {rmse:.4g}")
    ax1.axhline(
        float(np.median(errors)),
        color="tab:orange",
        ls=":",
        lw=1,
        label=f"median {np.median(errors):.4g}",
    )
    ax1.set_xlabel(label)
    ax1.set_ylabel(what)
    ax1.set_title(f"{what}: {est.name}")
    ax1.legend(fontsize=8)
    ax1.grid(True, alpha=0.3)
    p = est.p_W_B[s]
    a, b = _plane_axes(ref)
    pr = ref.p_W_B[thinned(len(ref))]
    ax2.plot(pr[:, a], pr[:, b], "--", color="0.5", lw=1, label="reference")
    sc = ax2.scatter(p[:, a], p[:, b], c=e, cmap="viridis", norm=norm, s=4)
    fig.colorbar(sc, ax=ax2, label=what)
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.set_xlabel(f"{'xyz'[a]} (m)")
    ax2.set_ylabel(f"{'xyz'[b]} (m)")
    ax2.set_title("Top view, coloured by error")
    ax2.legend(fontsize=8)
    fig.savefig(path, dpi=100)
    plt.close(fig)
