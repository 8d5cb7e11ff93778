"""``quadnav slam DATASET ...``: the stereo SLAM (ORB-SLAM2 class, thesis 002) over a dataset,
into a run folder with the estimate, metrics against the ground truth, plots and the report."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from quadnav.cli.common import (
    CommandParams,
    RerunConnectOpt,
    RerunSpawnOpt,
    check_range,
    command_help,
    console,
    handle_errors,
    optional_param,
    param,
    print_recording,
    progress_bar,
    rerun_param,
    rerun_request,
)
from quadnav.cli.link import open_serial
from quadnav.cli.planar import OutOpt
from quadnav.cli.vio import BlackoutOpt, OdometryRerunOpt, parse_blackout
from quadnav.errors import ConfigError
from quadnav.experiments.odometry_run import OdometryRun, OdometryRunOptions
from quadnav.experiments.slam_run import SlamRequest, check_slam_request, run_slam_source

if TYPE_CHECKING:
    from quadnav.viz.stream import RerunOptions

__all__ = ["EXAMPLES", "check_example", "resolve_slam_request", "slam_command"]


#: The map options of ``quadnav slam``.
SlamSaveMapOpt = Annotated[
    Path | None,
    typer.Option("--save-map", help="save the SLAM's map (keyframes, points) to this folder"),
]
SlamLoadMapOpt = Annotated[
    Path | None,
    typer.Option(
        "--load-map",
        help="start on a map saved by --save-map: relocalize in it, report in its frame",
    ),
]
LocalizationOpt = Annotated[
    bool,
    typer.Option(
        "--localization-only", help="with --load-map: track on the map without adding to it"
    ),
]
SlamLoopOpt = Annotated[
    bool,
    typer.Option("--loop/--no-loop", help="close loops (an SE(3) pose graph, points fused)"),
]
FinalBaOpt = Annotated[
    bool,
    typer.Option(
        "--final-ba/--no-final-ba",
        help="adjust every keyframe and point once more at the end: the final map, its "
        "trajectory (estimate_final.tum) and a saved map (the causal estimate is not touched)",
    ),
]


def resolve_slam_request(
    dataset: str, start_s: float, duration_s: float | None, seed: int, rig: str, out: Path,
    *, features: int = 1200, th_depth: float = 40.0, loop: bool = True, final_ba: bool = True,
    save_map: Path | None = None,
    load_map: Path | None = None, localization_only: bool = False, blackout: str | None = None,
    calibration: Path | None = None, rerun: RerunOptions | None = None,
    intrinsics: Path | None = None,
) -> SlamRequest:  # fmt: skip
    """The validated request (no dataset read, no folder made)."""
    check_range(start_s, "--start", 0.0, 1e6, "s")
    if duration_s is not None:
        check_range(duration_s, "--duration", 0.0, 1e6, "s", low_open=True)
    check_range(float(features), "--features", 50.0, 20000.0, "")
    check_range(th_depth, "--th-depth", 0.0, 1e4, "baselines", low_open=True)
    request = SlamRequest(
        source=dataset, seed=seed, rig=rig, out=out, n_features=features,
        th_depth_baselines=th_depth,
        options=OdometryRunOptions(start_s=start_s, duration_s=duration_s, video=False,
                                   blackout_s=parse_blackout(blackout)),
        loop=loop, final_ba=final_ba, save_map=save_map,
        load_map=load_map, localization_only=localization_only, calibration=calibration,
        rerun=rerun, intrinsics=intrinsics,
    )  # fmt: skip
    check_slam_request(request)
    return request


def check_example(params: CommandParams) -> None:
    """Validate an example's options as the command would, without running it."""
    resolve_slam_request(
        param(params, "dataset", str), param(params, "start_s", float),
        optional_param(params, "duration_s", float), param(params, "seed", int),
        param(params, "rig", str), param(params, "out", Path),
        features=param(params, "features", int), th_depth=param(params, "th_depth", float),
        loop=param(params, "loop", bool), final_ba=param(params, "final_ba", bool),
        save_map=optional_param(params, "save_map", Path),
        load_map=optional_param(params, "load_map", Path),
        localization_only=param(params, "localization_only", bool),
        blackout=optional_param(params, "blackout", str),
        calibration=optional_param(params, "calibration", Path), rerun=rerun_param(params),
        intrinsics=optional_param(params, "intrinsics", Path),
    )  # fmt: skip


#: The examples of ``quadnav slam --help`` (each parsed and validated by the tests).
EXAMPLES = (
    "quadnav slam room_easy --duration 10",
    "quadnav slam data/MH_01_easy --duration 30 --th-depth 22",
    "quadnav slam room_easy --duration 20 --save-map maps/room",
    "quadnav slam room_easy --seed 1 --load-map maps/room --localization-only",
    "quadnav slam room_easy --duration 30 --blackout 10:3 --no-loop",
    "quadnav slam data/V1_02_medium --intrinsics runs/first/final_intrinsics.json",
    "quadnav slam room_easy --rig rgbd --duration 20",
    "quadnav slam hall_laps --rig zed --features 1000 --out /tmp/runs",
    "quadnav slam room_laps --rerun",
)


def _table(run: OdometryRun) -> Table:
    """The run's numbers: the APE after SE(3) and Sim(3) alignment (the SLAM's world is not
    levelled: a position + yaw alignment would charge it the start's tilt), the frames with an
    estimate, losses, frames per second; the frames through the final map's keyframes (not
    causal: what ORB-SLAM2's saved trajectory is)."""
    m = run.metrics

    def ape(a: object) -> str:
        return a if isinstance(a, str) else f"{a.rmse_m:.4f}"  # type: ignore[attr-defined]

    table = Table(title=f"SLAM on {run.dataset}: {run.timing.frames} frames")
    cells = {
        "ATE SE(3) (m)": ape(m.ape_se3), "ATE Sim(3) (m)": ape(m.ape_sim3),
        "final map, SE(3) (m)": _final_ape(run),
        "with estimate": f"{100 * m.fraction_with_estimate:.0f} %", "losses": str(m.failures),
        "frames/s": f"{run.timing.frames_per_s:.1f}",
    }  # fmt: skip
    for c in cells:
        table.add_column(c, justify="right")
    table.add_row(*cells.values())
    return table


def _final_ape(run: OdometryRun) -> str:
    final = run.final or {}
    se3 = final.get("ape_se3")
    return f"{se3['rmse_m']:.4f}" if isinstance(se3, dict) else "n/a"


@handle_errors
def slam_command(
    dataset: Annotated[
        str,
        typer.Argument(help="stereo EuRoC folder, ROS bag, or built-in sequence (room_easy...)"),
    ],
    start_s: Annotated[float, typer.Option("--start", help="skip this many seconds")] = 0.0,
    duration_s: Annotated[
        float | None, typer.Option("--duration", help="seconds to run [default: to the end]")
    ] = None,
    seed: Annotated[int, typer.Option("--seed", min=0, help="seed of a built-in sequence")] = 0,
    rig: Annotated[
        str,
        typer.Option("--rig", help="the stereo or RGB-D rig a built-in sequence is made with"),
    ] = "euroc",
    features: Annotated[
        int, typer.Option("--features", help="ORB features a frame (thesis 002's Jetson: 1200)")
    ] = 1200,
    th_depth: Annotated[
        float,
        typer.Option(
            "--th-depth", help="ThDepth in baselines: nearer points are close (ORB-SLAM2 40)"
        ),
    ] = 40.0,
    loop: SlamLoopOpt = True,
    final_ba: FinalBaOpt = True,
    save_map: SlamSaveMapOpt = None,
    load_map: SlamLoadMapOpt = None,
    localization_only: LocalizationOpt = False,
    blackout: BlackoutOpt = None,
    calibration: Annotated[
        Path | None,
        typer.Option(
            "--calibration",
            help="Kalibr camchain or EuRoC folder replacing the dataset's calibration",
        ),
    ] = None,
    intrinsics: Annotated[
        Path | None,
        typer.Option(
            "--intrinsics",
            help="an earlier run's final_intrinsics.json: track in the calibration its final "
            "adjustment estimated (the rectified camera, and the distortion and the rig's turn "
            "it found, folded into the rectification)",
        ),
    ] = None,
    out: OutOpt = Path("runs"),
    serial: Annotated[
        str | None,
        typer.Option(
            "--serial",
            help="also send each position as thesis 002's X<cm>Y<cm>Z<cm>F "
            "frame at 10 Hz to this serial port (115200 8N1), as it is tracked",
        ),
    ] = None,
    rerun: OdometryRerunOpt = False,
    rerun_connect: RerunConnectOpt = None,
    rerun_spawn: RerunSpawnOpt = False,
) -> None:
    if calibration is not None and not calibration.exists():
        raise ConfigError(f"--calibration {calibration}: no such file or folder")
    request = resolve_slam_request(
        dataset, start_s, duration_s, seed, rig, out, features=features, th_depth=th_depth,
        loop=loop, final_ba=final_ba, save_map=save_map, load_map=load_map,
        localization_only=localization_only, blackout=blackout, calibration=calibration,
        rerun=rerun_request(rerun, rerun_connect, rerun_spawn), intrinsics=intrinsics,
    )  # fmt: skip
    link = None if serial is None else open_serial(serial, 115200)
    write = None if link is None else link.write  # type: ignore[attr-defined]
    try:
        with progress_bar("slam") as update:
            run = run_slam_source(request, update, serial=write)
    finally:
        if link is not None:
            link.close()  # type: ignore[attr-defined]
    console.print(_table(run))
    for n in run.notes:
        console.print(f"note: {n}", highlight=False)
    print_recording(run_dir=run.run_dir)
    console.print(str(run.run_dir), soft_wrap=True, highlight=False)


slam_command.__doc__ = command_help(
    "Stereo and RGB-D visual SLAM (ORB-SLAM2 class) over a dataset: estimate, metrics, report; maps saved and reused.",
    "DATASET is a stereo or RGB-D EuRoC ASL folder, a ROS 1/2 bag, or a built-in sequence made "
    "once per --seed and --rig under OUT/datasets. The pair is rectified (or the image given "
    "its depth), ORB features matched across it, the camera tracked on the map of its covisible "
    "keyframes and the keyframes adjusted locally. Its world is the first body pose (no IMU): compare after an SE(3) "
    "alignment. After a loss it relocalizes on the map it kept; it closes loops (an SE(3) "
    "pose graph over its keyframes, the points fused; --no-loop: not). --save-map writes "
    "the map, --load-map starts on one (relocalizing in it), --localization-only tracks on it "
    "without adding to it.",
    examples=EXAMPLES,
)
