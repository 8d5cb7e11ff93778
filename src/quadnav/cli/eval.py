"""``quadnav eval``: compare estimated trajectories with a reference, or tabulate run folders."""

from __future__ import annotations

from contextlib import nullcontext
from pathlib import Path
from typing import Annotated, Any, Literal

import typer
from rich.table import Table

from quadnav.cli.common import CommandParams, command_help, console, handle_errors, progress_bar
from quadnav.errors import EvalError
from quadnav.eval.evaluate import EvalOptions, EvalRun, run_eval
from quadnav.eval.runs import compare_runs, format_table

__all__ = ["EXAMPLES", "check_example", "eval_command"]


PathsArg = Annotated[
    list[Path], typer.Argument(help="REF EST [EST ...], or RUN_DIR ... with --table")
]
TableOpt = Annotated[bool, typer.Option("--table", help="tabulate the metrics of run folders")]
TableFormatOpt = Annotated[str, typer.Option("--table-format", help="markdown or csv")]
FormatOpt = Annotated[
    str | None,
    typer.Option("--format", help="estimate format: tum, euroc, kitti, quadnav, rosbag, ulog"),
]
RefFormatOpt = Annotated[
    str | None, typer.Option("--ref-format", help="reference format (default: guessed)")
]
TopicOpt = Annotated[str | None, typer.Option("--topic", help="ROS bag topic")]
TMaxDiffOpt = Annotated[
    float, typer.Option("--t-max-diff", help="largest time gap of a matched pair (s, 0 to 1e6)")
]
TOffsetOpt = Annotated[
    float,
    typer.Option("--t-offset", help="added to estimate timestamps (s, at most 4e9 either way)"),
]
InterpolateOpt = Annotated[
    bool, typer.Option("--interpolate", help="interpolate the reference at estimate times")
]
AlignOpt = Annotated[str, typer.Option("--align", help="none, se3, sim3 or 4dof (position + yaw)")]
AlignFirstOpt = Annotated[
    int | None, typer.Option("--align-first", help="align on the first N poses only")
]
GravityAxisOpt = Annotated[
    str | None,
    typer.Option(
        "--gravity-axis",
        help="x, y or z: the vertical 4dof rotates about (default z; y for KITTI poses)",
    ),
]
RpeDeltaOpt = Annotated[float, typer.Option("--rpe-delta", help="RPE step, > 0 and at most 1e9")]
RpeUnitOpt = Annotated[str, typer.Option("--rpe-unit", help="frames, seconds or metres")]
AllPairsOpt = Annotated[
    bool, typer.Option("--all-pairs", help="RPE over all pairs, not consecutive ones")
]
PairsFromRefOpt = Annotated[
    bool,
    typer.Option(
        "--pairs-from-reference", help="RPE pairs by the reference's path, not the estimate's"
    ),
]
NoPlotsOpt = Annotated[bool, typer.Option("--no-plots", help="skip the figures")]
OutOpt = Annotated[Path, typer.Option("--out", help="folder that receives the run folder")]


@handle_errors
def eval_command(
    paths: PathsArg,
    table: TableOpt = False,
    table_format: TableFormatOpt = "markdown",
    fmt: FormatOpt = None,
    ref_format: RefFormatOpt = None,
    topic: TopicOpt = None,
    t_max_diff: TMaxDiffOpt = 0.01,
    t_offset: TOffsetOpt = 0.0,
    interpolate: InterpolateOpt = False,
    align: AlignOpt = "none",
    align_first: AlignFirstOpt = None,
    gravity_axis: GravityAxisOpt = None,
    rpe_delta: RpeDeltaOpt = 1.0,
    rpe_unit: RpeUnitOpt = "frames",
    all_pairs: AllPairsOpt = False,
    pairs_from_reference: PairsFromRefOpt = False,
    no_plots: NoPlotsOpt = False,
    out: OutOpt = Path("runs"),
) -> None:
    if table:
        if table_format not in ("markdown", "csv"):
            raise EvalError(f"--table-format must be markdown or csv, got {table_format!r}")
        tf: Literal["markdown", "csv"] = "csv" if table_format == "csv" else "markdown"
        typer.echo(format_table(compare_runs(paths), tf), nl=False)
        return
    if len(paths) < 2:
        raise EvalError(
            "give a reference and at least one estimate: quadnav eval REF EST [EST ...]"
        )
    opts = _options_of(locals())
    # A bar over several estimates; one estimate is one step (and rich's bar 70 ms of start-up).
    bar = progress_bar("eval") if len(paths) > 2 else nullcontext(None)
    with bar as update:
        result = run_eval(paths[0], paths[1:], opts, runs_root=out, progress=update)
    _print_results(result)


def _options_of(p: CommandParams) -> EvalOptions:
    """The validated options of the command's parameters (named as the function names them)."""
    return _options(
        ref_format=p["ref_format"],
        est_format=p["fmt"],
        topic=p["topic"],
        t_max_diff_s=p["t_max_diff"],
        t_offset_s=p["t_offset"],
        interpolate=p["interpolate"],
        align=p["align"],
        align_first_n=p["align_first"],
        gravity_axis=p["gravity_axis"],
        rpe_delta=p["rpe_delta"],
        rpe_unit=p["rpe_unit"],
        rpe_all_pairs=p["all_pairs"],
        rpe_pairs_from="reference" if p["pairs_from_reference"] else "estimate",
        plots=not p["no_plots"],
    )


def check_example(params: CommandParams) -> None:
    """Validate an example's options as the command would, without reading the files."""
    if not params["table"]:
        _options_of(params)


#: The examples of ``quadnav eval --help`` (each parsed and validated by the tests).
EXAMPLES = (
    "quadnav eval gt.txt orb.txt --align se3 --rpe-delta 10 --rpe-unit metres",
    "quadnav eval euroc/state_groundtruth_estimate0/data.csv vins.tum --align 4dof --interpolate",
    "quadnav eval KITTI_00_gt.txt KITTI_00_ORB.txt --align 4dof --gravity-axis y",
    "quadnav eval runs/run/handled/truth.csv runs/run/handled/delayed.csv",
    "quadnav eval --table runs/*",
)


eval_command.__doc__ = command_help(
    "Compare trajectories with a reference: APE, RPE, NEES, plots and an HTML report.",
    "Formats are guessed from the files (TUM, EuRoC, KITTI, quadnav CSV, ROS bags, PX4 ULogs); "
    "APE and RPE follow evo 1.38.1. With --table, one table of the metrics of run folders of "
    "any kind.",
    examples=EXAMPLES,
)


def _print_results(result: EvalRun) -> None:
    """Notes, a table per estimate, and the run folder last."""
    for note in result.notes:
        console.print(f"note: {note}", soft_wrap=True, highlight=False)
    cols = ("rmse", "mean", "median", "std", "min", "max")
    for res in result.results:
        t = Table(
            title=f"{res.name}: {res.n_matched} matched poses, alignment {res.alignment.method}"
        )
        t.add_column("metric")
        for col in cols:
            t.add_column(col, justify="right")
        for key, stats in res.metrics.named():
            t.add_row(key, *(f"{getattr(stats, c):.6g}" for c in cols))
        console.print(t)
    console.print(str(result.run_dir), soft_wrap=True, highlight=False)


def _options(**values: Any) -> EvalOptions:
    """The options; a bad value is a one-line error naming the user's option (``--t-offset``)."""
    return EvalOptions(**values)
