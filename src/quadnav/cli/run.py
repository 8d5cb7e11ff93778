"""``quadnav run``: the main job, with a built-in default scenario."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from quadnav.cli.common import console, handle_errors, progress_bar
from quadnav.cli.planar import JobsOpt, OutOpt, SeedsOpt, SetOpt, run_planar_from_cli
from quadnav.errors import ConfigError
from quadnav.eval.na import fmt_metric
from quadnav.eval.nav import run_nav_study
from quadnav.experiments.nav import NavScenario
from quadnav.io.config import load_config

__all__ = ["BUILTIN_RUNS", "run_command"]

#: Built-in scenarios of `quadnav run` (overrides on the NavScenario defaults).
_OUTDOOR = [
    "vision.enabled=false",
    "gps.enabled=true",
    "mag.enabled=true",
    "plan.height_m=5",
    "plan.square_m=20",
    "plan.speed_m_s=3",
    "plan.accel_m_s2=2",
    "plan.hold_s=3",
    "plan.yaw=along_track",
]

BUILTIN_RUNS: dict[str, list[str]] = {
    "indoor_vision": [],
    # The same flight on the pose shortcut (true pose + 1 cm noise): 3x faster, no images.
    "indoor_vision_pose": ["vision.source=pose"],
    "indoor_vision_truth_control": ["closed_loop=false"],
    # PX4's rotated external vision (thesis 000 eqs 3.7-3.8): the marker frame is turned 30
    # degrees and offset from the world, the heading is the magnetometer's.
    "indoor_vision_rotated": [
        "vision.source=pose",
        "mag.enabled=true",
        "estimator.vision_frame=rotate",
        "vision.frame_yaw_deg=30",
        "vision.frame_offset_m=[1.5,-0.7,0.0]",
    ],
    # A range finder to the floor next to the barometer.
    "indoor_vision_range": ["vision.source=pose", "range.enabled=true"],
    "outdoor_gps": _OUTDOOR,
    # Faults: each is a scenario and a test (tests/experiments/test_nav_faults.py).
    "fault_gps_glitch": [*_OUTDOOR, "faults.gps_glitch=[[25,28,20,0]]"],
    "fault_vision_jump": ["vision.source=pose", "vision.jumps=[[12.5,20,1.0,-0.5,0.0]]"],
    "fault_bad_samples": [
        "vision.source=pose",
        "faults.imu_nan_s=[3,6.5,12]",
        "faults.imu_repeat_s=[4,8]",
        "faults.vision_late_s=[[5,0.5],[13,1.0]]",
    ],
}


@handle_errors
def run_command(
    scenario: Annotated[
        str | None,
        typer.Argument(help="built-in scenario (see the list below) or a YAML file"),
    ] = None,
    set_: SetOpt = None,
    seeds: SeedsOpt = None,
    out: OutOpt = Path("runs"),
    jobs: JobsOpt = None,
) -> None:
    """Run the main job. With no arguments: the indoor vision flight of thesis 000.

    A quadrotor aligns on the ground, takes off to 1.5 m, holds, flies a 2 m square, holds and
    lands, flown by a cascaded PID on the navigation EKF's output predictor; a delayed
    external pose (30 Hz, 250 ms, 1 cm) drops out twice for 2 s. SCENARIO is a built-in name
    (indoor_vision, indoor_vision_truth_control, outdoor_gps, planar) or a YAML file.

    Examples:

      quadnav run

      quadnav run --seeds 20

      quadnav run --set vision.delay_s=0.1 --set plan.square_m=4

      quadnav run planar --seeds 20
    """
    if scenario == "planar":
        run_planar_from_cli(None, set_, seeds, out, jobs)
        return
    overrides = list(set_ or [])
    if seeds is not None:
        overrides.append(f"seeds={seeds}")
    if scenario is None or scenario in BUILTIN_RUNS:
        name = scenario or "indoor_vision"
        config = load_config(NavScenario, None, [f"name={name}", *BUILTIN_RUNS[name], *overrides])
    else:
        path = Path(scenario)
        if not path.exists():
            raise ConfigError(
                f"{scenario!r} is neither a built-in scenario ({', '.join([*BUILTIN_RUNS, 'planar'])}) nor a file"
            )
        config = load_config(NavScenario, path, overrides)
    with progress_bar(config.name, line_step=0) as update:
        study = run_nav_study(
            config, runs_root=out, progress=update, jobs=jobs or os.cpu_count() or 1
        )
    s = study.summary
    table = Table(title=f"{config.name}: {s['seeds']} seed(s) (median; worst case where marked)")
    table.add_column("metric")
    table.add_column("value", justify="right")
    rows = [
        ("output position RMSE in the air (m)", s["output_rmse_m"]),
        ("output position RMSE with vision (m)", s["output_rmse_with_vision_m"]),
        ("error at the end of a dropout, worst (m)", s["dropout_end_error_max_m"]),
        ("back under 3 cm after a dropout, worst (s)", s["dropout_recovery_max_s"]),
        ("hover horizontal error, worst (m)", s["hold_max_horizontal_error_m"]),
        ("delayed estimate RMSE (m)", s["delayed_rmse_m"]),
        ("attitude RMSE (deg)", s["attitude_rmse_deg"]),
        ("NEES, mean (15 states)", s["nees_mean"]),
        (
            "gyro bias error / true bias, 60 s after alignment or at the end",
            s["gyro_bias_error_fraction_median"],
        ),
        (
            "accel bias error / true bias, 60 s after alignment or at the end",
            s["accel_bias_error_fraction_median"],
        ),
    ]
    for k, v in rows:
        table.add_row(k, fmt_metric(v))
    for src, frac in s.get("nis_above_95pct_gate", {}).items():
        table.add_row(f"{src}: innovations beyond the 95 % gate", f"{frac:.1%}")
    console.print(table)
    console.print(str(study.run_dir), soft_wrap=True, highlight=False)
