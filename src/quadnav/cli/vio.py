"""``quadnav vio DATASET ...``: monocular visual-inertial odometry over a dataset, into a run
folder with the estimate, metrics against the ground truth, plots, the tracks' video and the
report; over several datasets or seeds, a study with a summary table."""

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
    err_console,
    handle_errors,
    optional_param,
    param,
    print_recording,
    progress_bar,
    rerun_param,
    rerun_request,
    strings_param,
)
from quadnav.cli.planar import OutOpt
from quadnav.errors import ConfigError
from quadnav.experiments.odometry_run import OdometryRun, OdometryRunOptions
from quadnav.experiments.odometry_study import (
    GROUP_HEADER,
    ROW_HEADER,
    OdometryStudy,
    group_cells,
    row_cells,
    row_of,
    run_odometry_study,
)
from quadnav.experiments.seeds import parse_seeds
from quadnav.experiments.vio_run import VioRequest, check_request, run_vio_source

if TYPE_CHECKING:
    from quadnav.viz.stream import RerunOptions

__all__ = ["EXAMPLES", "check_example", "resolve_request", "vio_command"]


#: ``--set`` of the VIO: its example is one of VioConfig's keys (the tests validate it).
VioSetOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--set", help="override one VioConfig field, e.g. --set window_keyframes=8 (repeatable)"
    ),
]


#: The loop closure options of ``quadnav vio`` (each turns loop closure on).
LoopSetOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--loop-set",
        help="override a loop closure setting, e.g. --loop-set max_drift_m=0.5 or "
        "graph.loop_sigma_m=0.03 (repeatable; turns --loop on)",
    ),
]
SaveMapOpt = Annotated[
    Path | None,
    typer.Option(
        "--save-map",
        help="save loop closure's map (keyframes, descriptors, landmarks, loops) to this "
        "folder at the end (turns --loop on)",
    ),
]
LoadMapOpt = Annotated[
    Path | None,
    typer.Option(
        "--load-map",
        help="start on a map saved by --save-map: held fixed, the run relocalizes in it and "
        "reports in its frame (turns --loop on)",
    ),
]
#: ``--final-ba`` of ``quadnav vio``.
FinalBaOpt = Annotated[
    bool,
    typer.Option(
        "--final-ba/--no-final-ba",
        help="at the end, optimise the whole run's graph at once (every keyframe's IMU, "
        "observations and the calibration): estimate_final.tum, not causal, as ORB-SLAM3 "
        "saves its trajectory; with --loop, the loops too; the whole graph is kept in "
        "memory (stereo at 20 Hz: about 200 MB a minute)",
    ),
]
#: ``--rerun`` of ``quadnav vio`` and ``quadnav slam``.
OdometryRerunOpt = Annotated[
    bool,
    typer.Option(
        "--rerun",
        help="write the run's rerun recording, recording.rrd, into its folder (quadnav\\[viz]): "
        "the camera's images with their features (downsampled, every n-th; viz.npz), the map, "
        "keyframes, loops, trajectories",
    ),
]
BlackoutOpt = Annotated[
    str | None,
    typer.Option(
        "--blackout",
        help="withhold the cameras' images for SECONDS from START (s after the first "
        "image), START:SECONDS: a test of relocalization",
    ),
]


def resolve_request(
    datasets: list[str],
    config: Path | None,
    set_: list[str],
    camera: str,
    start_s: float,
    duration_s: float | None,
    seed: int,
    seeds: str | None,
    rig: str | None,
    out: Path,
    *,
    video: bool,
    video_every: int = 1,
    calibration: Path | None = None,
    stereo: bool = False,
    loop: bool = False,
    blackout: str | None = None,
    save_map: Path | None = None,
    load_map: Path | None = None,
    loop_set: list[str] | None = None,
    rerun: RerunOptions | None = None,
    final_ba: bool = False,
) -> VioRequest:
    """The validated request (no dataset read, no folder made). ``--stereo`` uses the rig's
    second camera; a built-in sequence is then made with EuRoC's stereo rig unless ``--rig``
    names another."""
    check_range(start_s, "--start", 0.0, 1e6, "s")
    if duration_s is not None:
        check_range(duration_s, "--duration", 0.0, 1e6, "s", low_open=True)
    options = OdometryRunOptions(
        camera=camera, start_s=start_s, duration_s=duration_s, video=video,
        video_every=video_every, blackout_s=parse_blackout(blackout), save_map=save_map,
    )  # fmt: skip
    looping = loop or save_map is not None or load_map is not None or bool(loop_set)
    if final_ba and load_map is not None:
        raise ConfigError(
            "--final-ba: not with --load-map (the run reports in the map's frame, which the "
            "smoothing does not hold); --save-map --final-ba saves the smoothed keyframes"
        )
    rig_name = rig or ("euroc" if stereo else "euroc_mono")
    overrides = (
        *set_,
        *(["stereo=true"] if stereo else []),
        *(["final_smoothing=true"] if final_ba else []),
    )
    request = VioRequest(
        sources=tuple(datasets), config=config, overrides=overrides, options=options,
        seed=seed, seeds=parse_seeds(seeds) if seeds is not None else None, rig=rig_name,
        out=out, calibration=calibration,
        loop=looping,
        load_map=load_map, loop_overrides=tuple(loop_set or ()), rerun=rerun,
    )  # fmt: skip
    check_request(request)
    return request


def parse_blackout(text: str | None) -> tuple[float, float] | None:
    """``--blackout START:SECONDS`` (s after the first image; a length over 0)."""
    if text is None:
        return None
    try:
        a, d = (float(x) for x in text.split(":"))
    except ValueError:
        raise ConfigError(f"--blackout {text!r}: give START:SECONDS, e.g. 20:3") from None
    check_range(a, "--blackout's start", 0.0, 1e6, "s")
    check_range(d, "--blackout's length", 0.0, 1e4, "s", low_open=True)
    return a, d


def check_example(params: CommandParams) -> None:
    """Validate an example's options as the command would, without running it."""
    resolve_request(
        list(strings_param(params, "datasets")), optional_param(params, "config", Path),
        strings_param(params, "set_"), param(params, "camera", str),
        param(params, "start_s", float), optional_param(params, "duration_s", float),
        param(params, "seed", int), optional_param(params, "seeds", str),
        optional_param(params, "rig", str), param(params, "out", Path),
        video=param(params, "video", bool), video_every=param(params, "video_every", int),
        calibration=optional_param(params, "calibration", Path),
        stereo=param(params, "stereo", bool), loop=param(params, "loop", bool),
        blackout=optional_param(params, "blackout", str),
        save_map=optional_param(params, "save_map", Path),
        load_map=optional_param(params, "load_map", Path),
        loop_set=strings_param(params, "loop_set"), rerun=rerun_param(params),
        final_ba=param(params, "final_ba", bool),
    )  # fmt: skip


#: The examples of ``quadnav vio --help`` (each parsed and validated by the tests).
EXAMPLES = (
    "quadnav vio room_easy --duration 20 --video-every 2",
    "quadnav vio data/V1_01_easy --config examples/vins_euroc_config.yaml --no-video",
    "quadnav vio ../shared/data/euroc_micro --set window_keyframes=8",
    "quadnav vio room_easy hall_easy --seeds 0-4 --out /tmp/runs",
    "quadnav vio room_medium --stereo --duration 30 --no-video",
    "quadnav vio room_laps --stereo --loop --no-video",
    "quadnav vio hall_laps --stereo --loop-set detector.temporal_consistency=3 --no-video",
    "quadnav vio room_laps --stereo --save-map /tmp/room_map --no-video",
    "quadnav vio data/room_again --stereo --load-map /tmp/room_map --no-video",
    "quadnav vio hall_laps --stereo --loop --blackout 50:3 --no-video",
    "quadnav vio room_easy --duration 20 --no-video --rerun",
    "quadnav vio room_medium --stereo --final-ba --no-video",
)


def _print_run(run: OdometryRun) -> None:
    table = Table(title=f"VIO on {run.dataset}: {run.timing.frames} frames")
    for c in ROW_HEADER[2:]:
        table.add_column(c, justify="right")
    table.add_row(*row_cells(row_of(run, run.dataset, None))[2:])
    console.print(table)
    m = run.metrics
    final = (run.final or {}).get("ape_se3")
    smoothing = (run.final or {}).get("smoothing")
    if isinstance(final, dict) and isinstance(smoothing, dict):
        loops = smoothing.get("loops", 0)
        with_loops = f" with {loops} loops" if loops else ""
        console.print(
            f"final trajectory (--final-ba{with_loops}, not causal): APE after SE(3) "
            f"{final['rmse_m']:.4f} m",
            highlight=False,
        )
    said = set(run.notes)  # each reason a column is n/a, once (no ground truth: all of them)
    for label, value in (
        ("metrics", m.ape_4dof), ("drift final (%)", m.drift_final_pct),
        ("drift RPE (%)", m.drift_rpe_pct), ("NEES/6", m.nees_pose),
    ):  # fmt: skip
        if isinstance(value, str) and value.removeprefix("n/a: ") not in said:
            said.add(value.removeprefix("n/a: "))
            err_console.print(f"note: {label} {value}", highlight=False, soft_wrap=True)
    for n in run.notes:
        err_console.print(f"note: {n}", highlight=False)
    console.print(str(run.run_dir), soft_wrap=True, highlight=False)


def _print_study(study: OdometryStudy) -> None:
    for title, header, rows in (
        ("per run", ROW_HEADER, [row_cells(r) for r in study.rows]),
        ("per group", GROUP_HEADER, [group_cells(g) for g in study.groups]),
    ):
        table = Table(title=f"VIO study, {title}")
        for c in header:
            table.add_column(c, justify="left" if c in ("dataset", "group") else "right")
        for r in rows:
            table.add_row(*r)
        console.print(table)
    console.print(str(study.run_dir), soft_wrap=True, highlight=False)


def _is_sequence(source: str) -> bool:
    from quadnav.experiments.datasets import SEQUENCES

    return not Path(source).exists() and source in SEQUENCES


@handle_errors
def vio_command(
    datasets: Annotated[
        list[str],
        typer.Argument(help="EuRoC/TUM-VI folder, ROS bag, or built-in sequence (room_easy...)"),
    ],
    config: Annotated[
        Path | None,
        typer.Option("--config", help="VINS-Mono's config YAML, or ours (VioConfig's fields)"),
    ] = None,
    set_: VioSetOpt = None,
    calibration: Annotated[
        Path | None,
        typer.Option("--calibration", help="Kalibr camchain or EuRoC folder (a bag's rig)"),
    ] = None,
    camera: Annotated[str, typer.Option("--camera", help="the rig's camera to use")] = "cam0",
    start_s: Annotated[float, typer.Option("--start", help="skip this many seconds")] = 0.0,
    duration_s: Annotated[
        float | None, typer.Option("--duration", help="seconds to run [default: to the end]")
    ] = None,
    seed: Annotated[int, typer.Option("--seed", min=0, help="seed of a built-in sequence")] = 0,
    seeds: Annotated[
        str | None, typer.Option("--seeds", help="a study over seeds: 0-4, or 0,2,7")
    ] = None,
    rig: Annotated[
        str | None,
        typer.Option(
            "--rig",
            help="rig a built-in sequence is made with [default: euroc_mono; euroc with --stereo]",
        ),
    ] = None,
    stereo: Annotated[
        bool, typer.Option("--stereo", help="stereo-inertial: the rig's second camera too")
    ] = False,
    loop: Annotated[
        bool,
        typer.Option(
            "--loop",
            help="loop closure: recognise revisited places, verify them, correct the drift "
            "with a 4-DoF pose graph",
        ),
    ] = False,
    loop_set: LoopSetOpt = None,
    save_map: SaveMapOpt = None,
    load_map: LoadMapOpt = None,
    blackout: BlackoutOpt = None,
    out: OutOpt = Path("runs"),
    video: Annotated[
        bool, typer.Option("--video/--no-video", help="write tracks.mp4 of the features")
    ] = True,
    video_every: Annotated[
        int, typer.Option("--video-every", min=1, help="draw every n-th frame in the video")
    ] = 1,
    rerun: OdometryRerunOpt = False,
    rerun_connect: RerunConnectOpt = None,
    rerun_spawn: RerunSpawnOpt = False,
    final_ba: FinalBaOpt = False,
) -> None:
    if calibration is not None and not calibration.exists():  # (a documented example's need not)
        raise ConfigError(f"--calibration {calibration}: no such file or folder")
    request = resolve_request(
        datasets, config, list(set_ or []), camera, start_s, duration_s, seed, seeds, rig, out,
        video=video, video_every=video_every, calibration=calibration, stereo=stereo, loop=loop,
        blackout=blackout, save_map=save_map, load_map=load_map, loop_set=loop_set,
        rerun=rerun_request(rerun, rerun_connect, rerun_spawn), final_ba=final_ba,
    )  # fmt: skip
    if len(datasets) == 1 and seeds is None:
        with progress_bar("vio") as update:
            run = run_vio_source(request, datasets[0], seed, out, update)
        _print_run(run)
        print_recording(run_dir=run.run_dir)
        return
    with progress_bar("vio study", line_step=0) as update:
        study = run_odometry_study(
            datasets, request.seeds,
            lambda src, s, where: run_vio_source(request, src, s, where), out,
            is_sequence=_is_sequence, progress=update,
        )  # fmt: skip
    _print_study(study)


vio_command.__doc__ = command_help(
    "Visual-inertial odometry (VINS-Mono class; stereo-inertial with --stereo) over a dataset: estimate, metrics, video, report.",
    "DATASET is an EuRoC ASL or TUM-VI folder, a ROS 1/2 bag, or a built-in sequence, made "
    "once per --seed and --rig under OUT/datasets. Without --config the dataset's own "
    "calibration is used. Metrics against the ground truth: APE after a position + yaw "
    "alignment (also SE(3) and Sim(3)), RPE, drift in % of the distance travelled (n/a "
    "under 1 m travelled), the "
    "gravity error, the pose NEES. Several DATASETs or --seeds run a study with a summary.",
    examples=EXAMPLES,
)
