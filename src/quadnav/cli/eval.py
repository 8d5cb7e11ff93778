"""``quadnav eval``: compare estimated trajectories with a reference, or tabulate run folders."""

from __future__ import annotations

from contextlib import nullcontext
from pathlib import Path
from typing import Annotated, Literal

import typer
from rich.table import Table

from quadnav.cli.common import console, handle_errors, progress_bar
from quadnav.errors import EvalError
from quadnav.eval.evaluate import OPTION_NAMES, EvalOptions, run_eval
from quadnav.eval.runs import compare_runs, format_table

__all__ = ["eval_command"]


@handle_errors
def eval_command(
    paths: Annotated[
        list[Path], typer.Argument(help="REF EST [EST ...], or RUN_DIR ... with --table")
    ],
    table: Annotated[
        bool, typer.Option("--table", help="tabulate the metrics of run folders")
    ] = False,
    table_format: Annotated[
        str, typer.Option("--table-format", help="markdown or csv")
    ] = "markdown",
    fmt: Annotated[
        str | None,
        typer.Option("--format", help="estimate format: tum, euroc, kitti, quadnav, rosbag, ulog"),
    ] = None,
    ref_format: Annotated[
        str | None, typer.Option("--ref-format", help="reference format (default: guessed)")
    ] = None,
    topic: Annotated[str | None, typer.Option("--topic", help="ROS bag topic")] = None,
    t_max_diff: Annotated[
        float,
        typer.Option("--t-max-diff", help="largest time gap of a matched pair (s, 0 to 1e6)"),
    ] = 0.01,
    t_offset: Annotated[
        float,
        typer.Option("--t-offset", help="added to estimate timestamps (s, at most 4e9 either way)"),
    ] = 0.0,
    interpolate: Annotated[
        bool, typer.Option("--interpolate", help="interpolate the reference at estimate times")
    ] = False,
    align: Annotated[
        str, typer.Option("--align", help="none, se3, sim3 or 4dof (position + yaw)")
    ] = "none",
    align_first: Annotated[
        int | None, typer.Option("--align-first", help="align on the first N poses only")
    ] = None,
    gravity_axis: Annotated[
        str | None,
        typer.Option(
            "--gravity-axis",
            help="x, y or z: the vertical 4dof rotates about (default z; y for KITTI poses)",
        ),
    ] = None,
    rpe_delta: Annotated[
        float, typer.Option("--rpe-delta", help="RPE step, > 0 and at most 1e9")
    ] = 1.0,
    rpe_unit: Annotated[
        str, typer.Option("--rpe-unit", help="frames, seconds or metres")
    ] = "frames",
    all_pairs: Annotated[
        bool, typer.Option("--all-pairs", help="RPE over all pairs, not consecutive ones")
    ] = False,
    pairs_from_reference: Annotated[
        bool,
        typer.Option(
            "--pairs-from-reference", help="RPE pairs by the reference's path, not the estimate's"
        ),
    ] = False,
    no_plots: Annotated[bool, typer.Option("--no-plots", help="skip the figures")] = False,
    out: Annotated[Path, typer.Option("--out", help="folder that receives the run folder")] = Path(
        "runs"
    ),
) -> None:
    """Compare trajectories with a reference: APE, RPE, NEES, plots and an HTML report.

    Examples:

      quadnav eval gt.txt orb.txt --align se3 --rpe-delta 10 --rpe-unit metres

      quadnav eval data.csv vins.tum --align 4dof --interpolate

      quadnav eval --table runs/2026-*_eval
    """
    if table:
        if table_format not in ("markdown", "csv"):
            raise EvalError(f"--table-format must be markdown or csv, got {table_format!r}")
        rows = compare_runs(paths)
        tf: Literal["markdown", "csv"] = "csv" if table_format == "csv" else "markdown"
        typer.echo(format_table(rows, tf), nl=False)
        return
    if len(paths) < 2:
        raise EvalError(
            "give a reference and at least one estimate: quadnav eval REF EST [EST ...]"
        )
    opts = _options(
        ref_format=ref_format,
        est_format=fmt,
        topic=topic,
        t_max_diff_s=t_max_diff,
        t_offset_s=t_offset,
        interpolate=interpolate,
        align=align,
        align_first_n=align_first,
        gravity_axis=gravity_axis,
        rpe_delta=rpe_delta,
        rpe_unit=rpe_unit,
        rpe_all_pairs=all_pairs,
        rpe_pairs_from="reference" if pairs_from_reference else "estimate",
        plots=not no_plots,
    )
    # A bar over several estimates; one estimate is one step (and rich's bar 70 ms of start-up).
    bar = progress_bar("eval") if len(paths) > 2 else nullcontext(None)
    with bar as update:
        result = run_eval(paths[0], paths[1:], opts, runs_root=out, progress=update)
    for note in result.notes:
        console.print(f"note: {note}", soft_wrap=True, highlight=False)
    for res in result.results:
        t = Table(
            title=f"{res.name}: {res.n_matched} matched poses, alignment {res.alignment.method}"
        )
        t.add_column("metric")
        for col in ("rmse", "mean", "median", "std", "min", "max"):
            t.add_column(col, justify="right")
        for key, stats in res.metrics.items():
            t.add_row(
                key, *(f"{stats[c]:.6g}" for c in ("rmse", "mean", "median", "std", "min", "max"))
            )
        console.print(t)
    console.print(str(result.run_dir), soft_wrap=True, highlight=False)


def _options(**values: object) -> EvalOptions:
    """The options, or a one-line error naming the user's option (``--t-offset``)."""
    from pydantic import ValidationError

    try:
        return EvalOptions.model_validate(values)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = str(err["loc"][0]) if err["loc"] else ""
        option = OPTION_NAMES.get(field, field)
        raise EvalError(f"{option}: {err['msg']} (got {err.get('input')!r})") from None
