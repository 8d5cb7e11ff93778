"""``quadnav dataset``: make visual-inertial datasets in 3-D worlds, read any dataset, and
measure how well features track in it."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from quadnav.cli.common import (
    CommandParams,
    command_help,
    console,
    handle_errors,
    optional_param,
    param,
    progress_bar,
    strings_param,
)
from quadnav.errors import ConfigError
from quadnav.experiments.datasets import SEQUENCES, SequenceSpec, make_dataset, sequence_spec

__all__ = ["EXAMPLES", "check_example", "dataset_app", "resolve_make"]

dataset_app = typer.Typer(
    help="Visual-inertial datasets: make them in 3-D worlds, read EuRoC/TUM-VI/bags/KITTI, track features.",
    no_args_is_help=True,
)


def resolve_make(
    name: str, motion: str | None, rig: str | None, seed: int | None, duration_s: float | None,
    set_: list[str],
) -> SequenceSpec:
    """The validated sequence ``dataset make`` would write (no work, no folder)."""
    options = {"motion": motion, "rig": rig, "seed": seed, "duration_s": duration_s}
    return sequence_spec(name, {k: v for k, v in options.items() if v is not None}, set_)


def check_example(params: CommandParams) -> None:
    """Validate an example's options as ``dataset make`` would, without rendering."""
    resolve_make(
        param(params, "name", str),
        optional_param(params, "motion", str),
        optional_param(params, "rig", str),
        optional_param(params, "seed", int),
        optional_param(params, "duration_s", float),
        strings_param(params, "set_"),
    )


#: The examples of ``quadnav dataset make --help`` (each parsed and validated by the tests).
EXAMPLES = (
    "quadnav dataset make room_easy --out data/room_easy",
    "quadnav dataset make hall --motion ../shared/data/motions/euroc_MH_01_easy.txt --out data/mh01",
    "quadnav dataset make room --motion indoor_vision --rig thesis003_sim --out data/flight",
    "quadnav dataset make room_difficult --rig zed --seed 3 --bag --out data/room_zed",
)


@dataset_app.command("make")
@handle_errors
def make_command(
    name: Annotated[str, typer.Argument(help="a built-in sequence or a world (listed above)")],
    out: Annotated[Path, typer.Option("--out", help="folder to write (mav0/ inside)")],
    motion: Annotated[
        str | None,
        typer.Option(
            "--motion",
            help="flight_path, a trajectory file (TUM, EuRoC...) or a quadnav run/sim scenario",
        ),
    ] = None,
    rig: Annotated[str | None, typer.Option("--rig", help="a built-in rig")] = None,
    seed: Annotated[int | None, typer.Option("--seed", help="seed of every stream")] = None,
    duration_s: Annotated[
        float | None, typer.Option("--duration", help="seconds of sequence (from its start)")
    ] = None,
    set_: Annotated[
        list[str] | None, typer.Option("--set", help="override a field: key=value")
    ] = None,
    bag: Annotated[bool, typer.Option("--bag", help="also write a ROS 2 bag (out/bag)")] = False,
) -> None:
    spec = resolve_make(name, motion, rig, seed, duration_s, set_ or [])
    if out.exists() and any(out.iterdir()):
        raise ConfigError(f"--out {out}: the folder exists and is not empty")
    with progress_bar(f"dataset {name}") as update:
        made = make_dataset(spec, out, name=name, progress=update, bag=bag)
    table = Table(title=f"{name}: {made.world} world, {made.rig} rig")
    table.add_column("what")
    table.add_column("value", justify="right")
    for k, v in (
        ("duration (s)", f"{made.duration_s:.1f}"),
        ("images", str(made.frames)),
        ("IMU samples", str(made.imu_samples)),
        ("distance (m)", f"{made.distance_m:.1f}"),
        ("mean speed (m/s)", f"{made.mean_speed_m_s:.2f}"),
        ("mean rotation rate (deg/s)", f"{made.mean_rate_deg_s:.1f}"),
        ("size (MB)", f"{made.size_bytes / 1e6:.1f}"),
        ("made in (s)", f"{made.seconds:.1f}"),
    ):
        table.add_row(k, v)
    console.print(table)
    console.print(str(made.root), soft_wrap=True, highlight=False)


make_command.__doc__ = command_help(
    "Render a visual-inertial dataset in a 3-D world along a motion and write it as an EuRoC "
    "ASL folder (mav0/cam*/, imu0/, state_groundtruth_estimate0/, sensor.yaml per sensor), "
    "with a Kalibr camchain, dataset.json and groundtruth.tum; --bag adds a ROS 2 bag.",
    lists=[("Built-in sequences", {n: s.description for n, s in SEQUENCES.items()})],
    examples=EXAMPLES,
)
