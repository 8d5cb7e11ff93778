"""A sweep's plots: each metric against each swept parameter, the median over the seeds (and
the other parameters) with a 10-90 % band; with two parameters, one line per value of the
other. It plots the table's columns, runs nothing."""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["plot_sweep", "value_label"]


def value_label(value: object) -> str:
    """A grid value as a label (and a key to group by): numbers and words as written."""
    if isinstance(value, str):
        return value
    if isinstance(value, float):
        return f"{value:g}"
    return json.dumps(value)


def _x(values: Sequence[object]) -> tuple[NDArray[np.float64], list[str], bool]:
    """Positions of a parameter's values on the x axis (the values themselves when they are
    all numbers, else 0, 1, ... in the order of the grid) and their labels."""
    labels = list(dict.fromkeys(value_label(v) for v in values))
    numeric = all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)
    if numeric:
        xs = sorted({float(v) for v in values})  # type: ignore[arg-type]
        return np.array(xs), [f"{x:g}" for x in xs], True
    return np.arange(len(labels), dtype=np.float64), labels, False


def _bands(
    x_of_row: NDArray[np.float64], y: NDArray[np.float64], xs: NDArray[np.float64]
) -> tuple[NDArray[np.float64], ...]:
    """Per x: the 10th, 50th and 90th percentiles of the finite values (NaN where none)."""
    out = np.full((3, len(xs)), np.nan)
    for k, x in enumerate(xs):
        v = y[(x_of_row == x) & np.isfinite(y)]
        if len(v):
            out[:, k] = np.percentile(v, [10, 50, 90])
    return out[0], out[1], out[2]


def _positions(
    values: Sequence[object], xs: NDArray[np.float64], labels: list[str], numeric: bool
) -> NDArray[np.float64]:
    if numeric:
        return np.array([float(v) for v in values])  # type: ignore[arg-type]
    where = {lab: float(k) for k, lab in enumerate(labels)}
    return np.array([where[value_label(v)] for v in values])


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", name)


def _plot_one(
    params: Mapping[str, Sequence[object]],
    metric: str,
    y: NDArray[np.float64],
    param: str,
    path: Path,
) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    values = params[param]
    xs, labels, numeric = _x(values)
    x_of_row = _positions(values, xs, labels, numeric)
    others = [p for p in params if p != param]
    group_by = others[0] if len(others) == 1 else None
    groups = list(dict.fromkeys(value_label(v) for v in params[group_by])) if group_by else [""]
    fig, ax = plt.subplots(figsize=(7, 4.5), constrained_layout=True)
    for g in groups:
        rows = (
            np.array([value_label(v) == g for v in params[group_by]])
            if group_by
            else np.ones(len(y), dtype=bool)
        )
        lo, med, hi = _bands(np.where(rows, x_of_row, np.nan), y, xs)
        label = f"{group_by} = {g}" if group_by else "median"
        (line,) = ax.plot(xs, med, "o-", label=label)
        ax.fill_between(xs, lo, hi, color=line.get_color(), alpha=0.2, lw=0)
    if not numeric:
        ax.set_xticks(xs, labels)
    ax.set_xlabel(param)
    ax.set_ylabel(metric)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    over = ", ".join(["seeds", *(o for o in others if o != group_by)])
    ax.set_title(f"{metric}: median, 10-90 % band over {over}", fontsize=9)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_sweep(
    params: Mapping[str, Sequence[object]],
    metrics: Mapping[str, NDArray[np.float64]],
    folder: Path,
) -> list[Path]:
    """``folder/<metric>__<param>.png`` for each metric (one value per row of the table, NaN
    where a task failed or the metric is n/a) with a finite value, against each parameter."""
    paths = []
    for metric, y in metrics.items():
        if not np.isfinite(y).any():
            continue
        for param in params:
            path = Path(folder) / f"{_safe(metric)}__{_safe(param)}.png"
            paths.append(_plot_one(params, metric, y, param, path))
    return paths
