"""The files of every kind of run folder: a declarative registry, one entry per command that
writes a run folder. The documentation's run-folder page is generated from it, and
``tests/docs/test_run_folders.py`` runs a small instance of each kind and checks that the files
written are the files declared (no undeclared file, no required file missing)."""

from __future__ import annotations

import fnmatch
from collections.abc import Iterable
from dataclasses import dataclass

__all__ = ["RUN_FOLDER_KINDS", "RunFile", "RunFolderKind", "check_run_files"]


@dataclass(frozen=True, slots=True)
class RunFile:
    """One file (or a family of files: ``pattern`` is a glob relative to the run folder)."""

    pattern: str
    description: str
    required: bool = True


@dataclass(frozen=True, slots=True, kw_only=True)
class RunFolderKind:
    """A kind of run folder: the command that writes it, its name and its files."""

    title: str
    command: str
    folder: str
    description: str
    files: tuple[RunFile, ...]


def check_run_files(kind: RunFolderKind, files: Iterable[str]) -> list[str]:
    """What is wrong with a folder's files (paths relative to it, ``/``-separated) against
    ``kind``: each file no pattern declares, each required pattern no file matches."""
    names = sorted(files)
    problems = [
        f"{name}: not declared in {kind.title!r}"
        for name in names
        if not any(fnmatch.fnmatchcase(name, f.pattern) for f in kind.files)
    ]
    problems += [
        f"{f.pattern}: declared as required in {kind.title!r} but not written"
        for f in kind.files
        if f.required and not any(fnmatch.fnmatchcase(n, f.pattern) for n in names)
    ]
    return problems


_COMMON = (
    RunFile("status.json", "running, complete, interrupted or failed (with the reason)"),
    RunFile("config.yaml", "the resolved configuration the run used"),
)


_RECORDING = (
    RunFile(
        "recording.rrd",
        "with --rerun (or written by quadnav view): the rerun recording of the folder's files",
        False,
    ),
    RunFile(
        "recording.json",
        "beside recording.rrd: its size, the rows of each stream and every how many of the "
        "files' rows each keeps, where it was streamed and what could not be done",
        False,
    ),
)


_NAV = RunFolderKind(
    title="quadnav run",
    command="quadnav run [SCENARIO]",
    folder="OUT/<stamp>_<scenario>/",
    description="A navigation flight (the first seed's series; every seed's metrics in "
    "seeds.jsonl). Which sensors' files appear depends on the scenario's sensors.",
    files=(
        *_COMMON,
        RunFile("metrics.json", "the summary over seeds and the first seed's metrics"),
        RunFile("seeds.jsonl", "one line of metrics per finished seed"),
        RunFile("report.html", "the report: metrics, plots, configuration"),
        RunFile("positions.csv", "truth, output predictor and setpoint positions (m)"),
        RunFile("delayed.csv", "the delayed horizon's state and position variance"),
        RunFile("truth.tum", "the true trajectory (TUM)"),
        RunFile("output.tum", "the output predictor's trajectory (TUM)"),
        RunFile("innovations_*.csv", "innovations, NIS, test ratio and acceptance per source"),
        RunFile("sensors_*.csv", "every sample the estimator was given, one file per sensor"),
        RunFile("vio.tum", "the odometry's own estimate of the rig's body (VIO, SLAM)", False),
        *_RECORDING,
        RunFile("plots/position.png", "positions against time"),
        RunFile("plots/errors.png", "errors with the filter's sigma"),
        RunFile("plots/innovations.png", "innovations per source", False),
        RunFile("plots/top_view.png", "the flight seen from above"),
    ),
)

_PLANAR_SERIES = (
    ("truth.csv", "the true state"),
    ("output.csv", "the output predictor's estimate"),
    ("delayed.csv", "the delayed horizon's estimate"),
    ("floor.csv", "the estimator's floor"),
    ("gps.csv", "the GPS measurements"),
    ("innovations.csv", "innovations and NIS"),
    ("truth.tum", "the true trajectory (TUM)"),
    ("output.tum", "the output trajectory (TUM)"),
    ("delayed.tum", "the delayed trajectory (TUM)"),
)

_PLANAR = RunFolderKind(
    title="quadnav planar",
    command="quadnav planar (or quadnav run planar)",
    folder="OUT/<stamp>_<name>/",
    description="Thesis 000's planar experiments: one subfolder per experiment (no_update, "
    "naive, handled) with the first seed's series.",
    files=(
        *_COMMON,
        RunFile("metrics.json", "the summary per experiment over seeds"),
        RunFile("seeds.jsonl", "one line of metrics per finished seed and experiment"),
        RunFile("report.html", "the report: metrics, plots, configuration"),
        *(RunFile(f"*/{name}", f"per experiment: {what}") for name, what in _PLANAR_SERIES),
        RunFile("plots/*.png", "one plot per experiment"),
        RunFile("plots/monte_carlo.png", "the errors over seeds (with several seeds)", False),
        *_RECORDING,
    ),
)

_SIM = RunFolderKind(
    title="quadnav sim",
    command="quadnav sim [SCENARIO]",
    folder="OUT/<stamp>_<scenario>/",
    description="A closed-loop flight on the true state, or (thesis 002's, "
    "position_source serial_truth or slam) on the position sent over a serial link.",
    files=(
        *_COMMON,
        RunFile(
            "metrics.json",
            "tracking errors, saturation, tilt, speed of the simulation; "
            "with a serial link its counts and the sent position's error (link)",
        ),
        RunFile("report.html", "the report: metrics, plots, configuration"),
        RunFile("states.csv", "the vehicle's state"),
        RunFile("controls.csv", "the controller's commands"),
        RunFile("trajectory.tum", "the flown trajectory (TUM)"),
        RunFile("plots/*.png", "positions, attitude, controls, top view"),
        RunFile(
            "link.csv", "with a serial link: each frame's time, position sent, true position", False
        ),
        RunFile(
            "plots/link.png",
            "with a serial link: sent (SLAM) against true against the reference",
            False,
        ),
        *_RECORDING,
    ),
)

_MARKERS = RunFolderKind(
    title="quadnav markers",
    command="quadnav markers SOURCE",
    folder="OUT/<stamp>_markers/",
    description="Marker detection and the vehicle's pose in every frame of a folder of "
    "images, a video or a camera.",
    files=(
        *_COMMON,
        RunFile("poses.csv", "the pose of every frame with one (written as the frames come)"),
        RunFile("stats.json", "frames, poses, rejections by reason, jitter, timing, notes"),
        RunFile("metrics.json", "the flat metrics (fraction with a pose, jitter, timing)"),
        RunFile("report.html", "the report: statistics, plots, configuration"),
        RunFile("plots/position.png", "the position from the markers", False),
        RunFile("plots/timing.png", "detection and pose time per frame", False),
        RunFile("overlay.mp4", "the frames with the detections drawn (video: true)", False),
        RunFile("images/frame_*.png", "the drawn frames (write_images: true)", False),
        *_RECORDING,
    ),
)

_REPLAY = RunFolderKind(
    title="quadnav replay",
    command="quadnav replay LOG.ulg",
    folder="OUT/<stamp>_replay_<log>/",
    description="A PX4 log's sensors through quadnav's navigation EKF, against PX4's estimate.",
    files=(
        *_COMMON,
        RunFile("quadnav.tum", "quadnav's estimate (TUM)"),
        RunFile("px4.tum", "PX4's estimate (TUM)", False),
        RunFile("truth.tum", "the ground truth of a SITL log (TUM)", False),
        RunFile("gnss_checks.csv", "PX4's GNSS checks per fix", False),
        RunFile("metrics.json", "quadnav against PX4 (and the truth), speed of the replay"),
        RunFile("report.html", "the report: metrics, plots, configuration"),
        RunFile("plots/position.png", "positions against time"),
        RunFile("plots/innovations.png", "innovations", False),
        *_RECORDING,
    ),
)

_EVAL = RunFolderKind(
    title="quadnav eval",
    command="quadnav eval REFERENCE ESTIMATE...",
    folder="OUT/<stamp>_eval/",
    description="Trajectories compared with a reference (evo's APE and RPE, NEES).",
    files=(
        *_COMMON,
        RunFile("metrics.json", "the metrics of every estimate"),
        RunFile("report.html", "the report: metrics, plots, configuration"),
        RunFile("aligned/*.tum", "each estimate aligned to the reference (TUM)"),
        RunFile("plots/xyz.png", "positions against time (without --no-plots)", False),
        RunFile("plots/trajectories.png", "the trajectories from above", False),
        RunFile("plots/ape_*.png", "each estimate's APE against time", False),
    ),
)

_VIO = RunFolderKind(
    title="quadnav vio",
    command="quadnav vio DATASET",
    folder="OUT/<stamp>_vio_<dataset>/",
    description="Visual-inertial odometry over a dataset. A built-in sequence is made first "
    "under OUT/datasets/ (as `quadnav dataset make` writes it) and reused.",
    files=(
        *_COMMON,
        RunFile("estimate.tum", "the VIO's estimate of the rig's body (TUM)"),
        RunFile("keyframes.tum", "the keyframes the VIO published, at their final estimates (TUM)"),
        RunFile(
            "estimate_final.tum",
            "each tracked frame through its keyframe's pose at the end: the window's, the "
            "last pose graph's (--loop), or the whole run smoothed (--final-ba, with the "
            "loops as factors with --loop); not causal; TUM",
            False,
        ),
        RunFile("groundtruth.tum", "the dataset's ground truth (TUM)", False),
        RunFile("events.jsonl", "initialisation, failures, resets, time offset, one a line"),
        RunFile("timing.json", "time per stage"),
        RunFile(
            "nees.csv",
            "each pose's NEES against the ground truth, its rotation's and its translation's "
            "alone (plotted in plots/nees.png)",
            False,
        ),
        RunFile(
            "calibration.json",
            "the VIO: each camera's extrinsic, intrinsics and time offset as stated and as "
            "refined online at the end, how far they moved, and each against the dataset's "
            "truth/ when it has one",
            False,
        ),
        RunFile(
            "camchain_online.yaml",
            "the VIO: the calibration refined online, at the end, as a Kalibr camchain: a later "
            "run with the same rig takes it with --calibration",
            False,
        ),
        RunFile(
            "metrics.json",
            "APE (4-DoF, SE(3), Sim(3)), RPE, drift, NEES, counts; with --loop the loops "
            "judged against the truth (loop_precision, loop_recall, ...)",
        ),
        RunFile("report.html", "the report: metrics, plots, configuration"),
        RunFile("plots/*.png", "trajectory, error and timing plots"),
        RunFile("tracks.mp4", "the tracked features drawn (without --no-video)", False),
        RunFile(
            "keyframes_loop.tum",
            "with --loop: the keyframes as the last pose graph has them (TUM)",
            False,
        ),
        RunFile(
            "keyframes_final.tum",
            "quadnav slam: its map's keyframes as they are at the end (after bundle adjustment "
            "and loop closing; culled ones left out) (TUM)",
            False,
        ),
        RunFile(
            "loop.json",
            "with --loop: keyframes, places recognised, loops accepted and their keyframes, "
            "rejections by verification stage",
            False,
        ),
        *_RECORDING,
        RunFile(
            "viz.npz",
            "with --rerun: what the camera showed, for the recording: every n-th image "
            "(image_every), downsampled (image_scale) and JPEG-encoded, the features tracked in "
            "them, each state's tracked count and position covariance, the landmarks",
            False,
        ),
    ),
)

_VIO_STUDY = RunFolderKind(
    title="quadnav vio (several datasets or seeds)",
    command="quadnav vio SEQ... --seeds 0-4",
    folder="OUT/<stamp>_vio_study/",
    description="One `quadnav vio` run folder per dataset and seed under runs/, and the "
    "tables over them.",
    files=(
        *_COMMON,
        RunFile("runs.jsonl", "one line per finished run"),
        RunFile("summary.json", "the runs and the means and medians per group"),
        RunFile("summary.md", "the same as Markdown tables"),
        RunFile("runs/*/*", "each run's folder (as `quadnav vio` writes it)"),
        RunFile("runs/*/plots/*.png", "each run's plots"),
    ),
)

_DATASET = RunFolderKind(
    title="quadnav dataset make",
    command="quadnav dataset make SEQUENCE --out FOLDER",
    folder="FOLDER/ (written as FOLDER.partial/, renamed when complete)",
    description="Not a run folder but a dataset: an EuRoC ASL folder with calibration files "
    "for Kalibr and OpenVINS. `mav0/cam1/` only for a stereo rig, `mav0/depth0/` for an RGB-D "
    "one. With realistic sensors (the default) `mav0/`'s calibration is what a user would have "
    "(the datasheet's IMU noise, a calibration error, no time offset); `truth/` holds the one "
    "the data was made with (`--calibration FOLDER/truth`).",
    files=(
        RunFile(
            "dataset.json",
            "what was made: the sequence, rig, seed, spans, and what the sensor profile drew "
            "(turn-on biases, time offset, calibration error; written last)",
        ),
        RunFile("groundtruth.tum", "the rig body's ground truth (TUM)"),
        RunFile("camchain.yaml", "Kalibr's camera chain"),
        RunFile("imu.yaml", "Kalibr's IMU noise"),
        RunFile("kalibr_imu_chain.yaml", "OpenVINS's IMU chain"),
        RunFile("kalibr_imucam_chain.yaml", "OpenVINS's camera-IMU chain"),
        RunFile("mav0/body.yaml", "the body frame"),
        RunFile("mav0/cam*/data.csv", "each camera's image stamps and file names"),
        RunFile("mav0/cam*/data/*.png", "each camera's images"),
        RunFile("mav0/cam*/sensor.yaml", "each camera's calibration and T_BS"),
        RunFile("mav0/depth*/data.csv", "the depth images' stamps (RGB-D rigs)", False),
        RunFile("mav0/depth*/data/*.png", "depth images in millimetres (RGB-D rigs)", False),
        RunFile("mav0/depth*/sensor.yaml", "the depth camera (RGB-D rigs)", False),
        RunFile("mav0/imu0/data.csv", "the IMU samples"),
        RunFile("mav0/imu0/sensor.yaml", "the IMU's noise and T_BS"),
        RunFile("mav0/state_groundtruth_estimate0/data.csv", "EuRoC's ground-truth CSV"),
        RunFile("mav0/state_groundtruth_estimate0/sensor.yaml", "the ground truth's sensor"),
        RunFile("bag/*", "the ROS 2 bag (--bag)", False),
        RunFile("truth/camchain.yaml", "the true calibration: Kalibr's camera chain"),
        RunFile("truth/imu.yaml", "the true calibration: Kalibr's IMU noise"),
        RunFile("truth/kalibr_imu_chain.yaml", "the true calibration: OpenVINS's IMU chain"),
        RunFile(
            "truth/kalibr_imucam_chain.yaml", "the true calibration: OpenVINS's camera-IMU chain"
        ),
        RunFile("truth/mav0/body.yaml", "the true calibration: the body frame"),
        RunFile("truth/mav0/cam*/sensor.yaml", "each camera's true calibration and time offset"),
        RunFile("truth/mav0/imu0/sensor.yaml", "the IMU noise the data was synthesized with"),
        *_RECORDING,
    ),
)

_SWEEP = RunFolderKind(
    title="quadnav sweep",
    command="quadnav sweep SCENARIO --grid KEY=SPEC --seeds N",
    folder="OUT/ (--out; default runs/sweep_<scenario>_<fingerprint>/)",
    description="A grid of configuration values x seeds, one task per (grid point, seed). "
    "The same sweep run again into the folder runs only the tasks tasks.jsonl does not hold; "
    "another sweep into it is refused. The plots and the report are written once every task "
    "has finished.",
    files=(
        *_COMMON,
        RunFile("sweep.json", "the sweep: kind, scenario, grid, seeds, --set, its fingerprint"),
        RunFile(
            "tasks.jsonl", "one line per finished task (append-only: the journal resumed from)"
        ),
        RunFile(
            "results.parquet",
            "one row per finished task: task, the grid's keys, seed, status, error, wall_s, "
            "one column per metric (null: failed or n/a)",
        ),
        RunFile("report.html", "the report: tasks, medians per grid point, failures, plots"),
        RunFile("plots/*__*.png", "each headline metric against each swept key (median, 10-90 %)"),
    ),
)

#: Every kind of run folder by a short name, in the order of the commands.
RUN_FOLDER_KINDS: dict[str, RunFolderKind] = {
    "run": _NAV,
    "planar": _PLANAR,
    "sim": _SIM,
    "markers": _MARKERS,
    "replay": _REPLAY,
    "eval": _EVAL,
    "vio": _VIO,
    "vio_study": _VIO_STUDY,
    "dataset_make": _DATASET,
    "sweep": _SWEEP,
}
