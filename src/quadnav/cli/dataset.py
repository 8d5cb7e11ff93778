"""``quadnav dataset``: make visual-inertial datasets in 3-D worlds, read any dataset, and
measure how well features track in it."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import numpy as np
import typer
from rich.table import Table

from quadnav.cli.common import (
    CommandParams,
    RerunConnectOpt,
    RerunOpt,
    RerunSpawnOpt,
    check_range,
    command_help,
    console,
    finish_recording,
    handle_errors,
    optional_param,
    param,
    progress_bar,
    rerun_param,
    rerun_request,
    start_recording,
    strings_param,
)
from quadnav.errors import ConfigError
from quadnav.experiments.datasets import SEQUENCES, SequenceSpec, make_dataset, sequence_spec
from quadnav.io.run_folder import write_text

if TYPE_CHECKING:
    from quadnav.io.datasets import VisualInertialDataset

__all__ = ["EXAMPLES", "check_example", "dataset_app", "resolve_make"]

dataset_app = typer.Typer(
    help="Visual-inertial datasets: make them in 3-D worlds, read EuRoC/TUM-VI/bags/KITTI, track features.",
    no_args_is_help=True,
)


def resolve_make(
    name: str,
    motion: str | None,
    rig: str | None,
    seed: int | None,
    duration_s: float | None,
    set_: list[str],
    sensors: str | None = None,
) -> SequenceSpec:
    """The validated sequence ``dataset make`` would write (no work, no folder): a motion file
    or scenario without ``--duration`` is made whole (:func:`sequence_spec`)."""
    options = {
        "motion": motion,
        "rig": rig,
        "seed": seed,
        "duration_s": duration_s,
        "sensors": sensors,
    }
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
        optional_param(params, "sensors", str),
    )
    rerun_param(params)


#: The examples of ``quadnav dataset make --help`` (each parsed and validated by the tests).
EXAMPLES = (
    "quadnav dataset make room_easy --out data/room_easy",
    "quadnav dataset make hall --motion ../shared/data/motions/euroc_MH_01_easy.txt --out data/mh01",
    "quadnav dataset make room --motion indoor_vision --rig thesis003_sim --out data/flight",
    "quadnav dataset make room_difficult --rig zed --seed 3 --bag --out data/room_zed",
    "quadnav dataset make room_medium --rig euroc_mono --sensors ideal --out data/room_ideal",
    "quadnav dataset make room_easy --duration 10 --rerun --out data/room_10s",
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
        float | None,
        typer.Option(
            "--duration",
            help="seconds of sequence (from its start) [default: a --motion file's or "
            "scenario's whole length, up to 1800 s; a built-in sequence's own]",
        ),
    ] = None,
    set_: Annotated[
        list[str] | None, typer.Option("--set", help="override a field: key=value")
    ] = None,
    bag: Annotated[bool, typer.Option("--bag", help="also write a ROS 2 bag (out/bag)")] = False,
    sensors: Annotated[
        str | None,
        typer.Option(
            "--sensors",
            help="realistic: IMU turn-on biases and in-flight noise, an unstated time offset, "
            "a calibration error (the truth in out/truth/) [default]; ideal: exact",
        ),
    ] = None,
    rerun: RerunOpt = False,
    rerun_connect: RerunConnectOpt = None,
    rerun_spawn: RerunSpawnOpt = False,
) -> None:
    spec = resolve_make(name, motion, rig, seed, duration_s, set_ or [], sensors)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: is a file, not a folder")
    if out.exists() and any(out.iterdir()):
        raise ConfigError(f"--out {out}: the folder exists and is not empty")
    recorder = start_recording(rerun_request(rerun, rerun_connect, rerun_spawn))
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
    finish_recording(recorder, made.root, "dataset")
    console.print(str(made.root), soft_wrap=True, highlight=False)


make_command.__doc__ = command_help(
    "Render a visual-inertial dataset in a 3-D world along a motion and write it as an EuRoC "
    "ASL folder (mav0/cam*/, imu0/, state_groundtruth_estimate0/, sensor.yaml per sensor), "
    "with a Kalibr camchain, dataset.json and groundtruth.tum; --bag adds a ROS 2 bag. "
    "Sensors are realistic unless --sensors ideal: the IMU's turn-on biases drawn from its "
    "rig's spread and its noise at the level a real one shows in flight (imu0/sensor.yaml "
    "states the datasheet's), a camera-IMU time offset of a few ms that the calibration does "
    "not state, and a calibration error in cam*/sensor.yaml; the true calibration is in "
    "OUT/truth/ (quadnav vio OUT --calibration OUT/truth uses it), what was drawn in "
    "dataset.json.",
    lists=[("Built-in sequences", {n: s.description for n, s in SEQUENCES.items()})],
    examples=EXAMPLES,
)


DatasetArg = Annotated[
    Path, typer.Argument(help="an EuRoC or TUM-VI folder, a KITTI sequence, or a ROS 1/2 bag")
]
CalibOpt = Annotated[
    Path | None,
    typer.Option(
        "--calibration", help="a Kalibr camchain or EuRoC folder replacing the files' own"
    ),
]


def _open(path: Path, calibration: Path | None) -> VisualInertialDataset:
    from quadnav.io.datasets import open_dataset

    return open_dataset(path, calibration=calibration)


@dataset_app.command("info")
@handle_errors
def info_command(dataset: DatasetArg, calibration: CalibOpt = None) -> None:
    """What a dataset holds: its kind, cameras and their calibration, IMU, ground truth, span,
    and the samples refused on reading."""
    ds = _open(dataset, calibration)
    table = Table(title=f"{ds.name} ({ds.kind})")
    table.add_column("what")
    table.add_column("value")
    for cam in ds.rig.cameras:
        K = cam.camera.K
        table.add_row(
            cam.name,
            f"{len(ds.frames_of(cam.name))} frames, {cam.rate_hz:g} Hz, "
            f"{cam.camera.width}x{cam.camera.height}, fx {K[0, 0]:.1f} fy {K[1, 1]:.1f}, "
            f"{cam.camera.model}, p_B_C {np.round(cam.T_B_C.p_A_B, 4).tolist()}",
        )
    if ds.rig.stereo:
        table.add_row("stereo baseline", f"{ds.rig.baseline_m * 1000:.1f} mm")
    imu = ds.rig.imu
    table.add_row("IMU", f"{len(ds.imu)} samples at {imu.rate_hz:g} Hz" if imu else "none")
    gt = ds.groundtruth
    table.add_row("ground truth", f"{len(gt)} poses" if gt is not None else "none")
    table.add_row("span", f"{ds.duration_s:.2f} s")
    table.add_row("refused on reading", ds.issues.summary() if ds.issues else "nothing")
    console.print(table)


@dataset_app.command("tracks")
@handle_errors
def tracks_command(
    dataset: DatasetArg,
    camera: Annotated[str, typer.Option("--camera", help="camera to track")] = "cam0",
    start_s: Annotated[float, typer.Option("--start", help="seconds from the first frame")] = 0.0,
    duration_s: Annotated[
        float | None, typer.Option("--duration", help="seconds to track [default: to the end]")
    ] = None,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="write the statistics to this file")
    ] = None,
    calibration: CalibOpt = None,
) -> None:
    """Track GFTT corners with pyramidal KLT (VINS-Mono's front end) through a camera's images:
    median track length, fraction tracked frame to frame, corners, brightness and contrast."""
    from quadnav.experiments.track_study import track_dataset

    check_range(start_s, "--start", 0.0, 1e6, "s")
    if duration_s is not None:
        check_range(duration_s, "--duration", 0.0, 1e6, "s", low_open=True)
    ds = _open(dataset, calibration)
    with progress_bar("tracks"):
        study = track_dataset(ds, camera=camera, start_s=start_s, duration_s=duration_s)
    t, im = study.tracks, study.images
    table = Table(title=f"{ds.name} {camera}: {t.n_frames} frames over {study.duration_s:.1f} s")
    table.add_column("metric")
    table.add_column("median", justify="right")
    for k, v in (
        ("track length (frames, all tracks)", f"{t.track_length.median:.1f}"),
        ("track length (frames, ended tracks)", f"{t.ended_track_length.median:.1f}"),
        ("fraction tracked frame to frame", f"{t.fraction_tracked.median:.3f}"),
        ("features per frame", f"{t.features_per_frame.median:.0f}"),
        ("new features per frame", f"{t.new_per_frame.median:.1f}"),
        ("GFTT corners (q 0.01, 10 px)", f"{im.corners:.0f}"),
        ("mean grey / contrast", f"{im.mean_grey:.0f} / {im.contrast:.1f}"),
        ("mean gradient (grey/px)", f"{im.gradient:.2f}"),
    ):
        table.add_row(k, v)
    console.print(table)
    if json_out is not None:
        write_text(json_out, json.dumps(study.to_json(), indent=2) + "\n")
