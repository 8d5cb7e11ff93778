"""The VIO run's folder, its completeness and its bad inputs, and the summary over seeds and
datasets, driven by a test double whose errors are known (the ground truth plus Gaussian noise
of the covariance it reports)."""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from pydantic import Field
from scipy.spatial.transform import Rotation

from quadnav.config_model import ConfigModel
from quadnav.errors import ConfigError, IoError
from quadnav.eval.na import is_na
from quadnav.eval.vio_metrics import ApeSummary, NeesSummary
from quadnav.experiments.odometry_run import (
    OdometryRun,
    OdometryRunOptions,
    dataset_cache_folder,
    resolve_dataset,
    run_odometry,
)
from quadnav.experiments.odometry_study import group_of, run_odometry_study
from quadnav.experiments.seeds import parse_seeds
from quadnav.experiments.vio_run import resolve_vio_config
from quadnav.geometry import Pose
from quadnav.io.datasets import VisualInertialDataset, open_dataset
from quadnav.io.run_folder import read_run_status, run_guard
from quadnav.io.trajectory_io import read_tum
from quadnav.odometry import CameraCalibration
from quadnav.rig import Rig
from quadnav.vision.tracking import TrackerConfig
from tests.experiments.vio_double import SIGMAS, TruthPlusNoise
from tests.io.test_vins_config import EUROC_LIKE
from tests.shared_data import SHARED, needs

SECONDS = 3.0


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 s of the room, made as ``quadnav vio room_easy`` makes a built-in sequence."""
    root = tmp_path_factory.mktemp("vio_cache")
    ds = resolve_dataset("room_easy", seed=0, duration_s=SECONDS, cache_root=root)
    return ds.root


def _double(ds: VisualInertialDataset, **kw: object) -> TruthPlusNoise:
    assert ds.groundtruth is not None
    return TruthPlusNoise(ds.groundtruth.trajectory, **kw)  # type: ignore[arg-type]


def _run(ds: VisualInertialDataset, out: Path, double: TruthPlusNoise, **opt: object):  # type: ignore[no-untyped-def]
    with run_guard():
        return run_odometry(
            ds,
            ds.rig,
            lambda rig: double,
            out,
            config_text="k: 1\n",
            options=OdometryRunOptions(**opt),
        )  # type: ignore[arg-type]


def _phase_counts(ds: VisualInertialDataset, init_s: float, fail_s: float, reinit_s: float) -> int:
    t = np.array([f.t_ns for f in ds.frames_of("cam0")])
    t_s = (t - t[0]) * 1e-9
    return int(np.sum((t_s >= init_s) & ~((t_s >= fail_s) & (t_s < fail_s + reinit_s))))


def test_run_folder_holds_every_output_and_is_complete(made: Path, tmp_path: Path) -> None:
    ds = open_dataset(made)
    run = _run(ds, tmp_path, _double(ds, fail_at_s=1.5, reinit_after_s=0.3))
    d = run.run_dir
    for name in ("estimate.tum", "groundtruth.tum", "metrics.json", "events.jsonl", "timing.json",
                 "tracks.mp4", "report.html", "config.yaml", "plots/trajectory.png",
                 "plots/error.png", "plots/timing.png", "nees.csv", "plots/nees.png"):  # fmt: skip
        assert (d / name).is_file(), name
    assert read_run_status(d) == "complete"
    frames = len(ds.frames_of("cam0"))
    m = run.metrics
    assert m.frames == frames
    assert m.frames_with_estimate == _phase_counts(ds, 0.5, 1.5, 0.3)
    assert len(read_tum(d / "estimate.tum")) == m.frames_with_estimate
    assert (m.failures, m.reinitializations, m.rejected_images) == (1, 1, 0)
    kinds = [json.loads(line)["kind"] for line in (d / "events.jsonl").read_text().splitlines()]
    assert kinds == ["initialized", "failure", "reinitialized"]
    # 3 cm per axis: the error's RMS norm is 3 cm * sqrt(3); ~45 poses, so 25 % either way
    assert isinstance(m.ape_4dof, ApeSummary)
    assert m.ape_4dof.rmse_m == pytest.approx(SIGMAS[3] * np.sqrt(3), rel=0.25)
    assert isinstance(m.nees_pose, NeesSummary) and 0.7 < m.nees_pose.mean_over_dof < 1.3
    assert isinstance(m.gravity_error_deg, float) and m.gravity_error_deg < 1.0
    assert m.initialized_after_s == pytest.approx(
        0.5, abs=0.051
    )  # the first frame at or after 0.5 s
    nees = np.genfromtxt(d / "nees.csv", delimiter=",", names=True)
    assert len(nees) == m.frames_with_estimate  # every estimate has its truth here
    assert nees["nees_pose"].mean() / 6 == pytest.approx(m.nees_pose.mean_over_dof)
    # the double's errors are drawn from the covariance it claims, rotation and translation
    for part in ("nees_rotation", "nees_translation"):
        assert 0.6 < nees[part].mean() / 3 < 1.5, (part, nees[part].mean() / 3)
    saved = json.loads((d / "metrics.json").read_text())
    assert saved["ape_4dof"]["rmse_m"] == pytest.approx(m.ape_4dof.rmse_m)
    assert saved["timing"]["frames"] == frames and "track" in saved["timing"]["stage_ms_per_call"]
    video = cv2.VideoCapture(str(d / "tracks.mp4"))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == frames
    video.release()


def test_a_recovery_is_counted_and_breaks_nothing(made: Path, tmp_path: Path) -> None:
    """A ``recovered`` event (a solve redone with QR, or the window restarted in place) is
    counted in the metrics and the report; the estimate goes on at every frame, no failure."""
    ds = open_dataset(made)
    run = _run(ds, tmp_path, _double(ds, recover_at_s=1.0))
    m = run.metrics
    assert (m.recoveries, m.failures, m.reinitializations) == (1, 0, 0)
    assert m.frames_with_estimate == _phase_counts(ds, 0.5, 1e9, 0.0)
    assert json.loads((run.run_dir / "metrics.json").read_text())["recoveries"] == 1
    assert "failures, re-initialisations, recoveries" in (run.run_dir / "report.html").read_text()


def test_the_report_rounds_its_numbers_and_the_json_keeps_them(made: Path, tmp_path: Path) -> None:
    """Issue 21, item 14: the report printed metrics with 15 digits."""
    ds = open_dataset(made)
    run = _run(ds, tmp_path, _double(ds), video=False)
    html = (run.run_dir / "report.html").read_text()
    metrics = html.split("<h2>Metrics</h2>")[1].split("<h2>Events</h2>")[0]
    cells = re.findall(r"<td>([^<]*)</td>", metrics)
    numbers = [x for c in cells for x in re.findall(r"\d+\.\d+(?:e-?\d+)?", c)]
    assert numbers and all(len(re.sub(r"\D|e.*", "", x).lstrip("0")) <= 4 for x in numbers), numbers
    saved = json.loads((run.run_dir / "metrics.json").read_text())
    assert isinstance(run.metrics.ape_4dof, ApeSummary)
    assert saved["ape_4dof"]["median_m"] == run.metrics.ape_4dof.median_m  # every digit


def test_start_and_duration_choose_the_span(made: Path, tmp_path: Path) -> None:
    ds = open_dataset(made)
    run = _run(
        ds, tmp_path, _double(ds, init_after_s=0.0), start_s=1.0, duration_s=1.0, video=False
    )
    assert run.metrics.frames == 21  # 20 Hz over a closed 1 s span
    assert not (run.run_dir / "tracks.mp4").exists()
    gt = read_tum(run.run_dir / "groundtruth.tum")
    assert (gt.t_ns[-1] - gt.t_ns[0]) * 1e-9 == pytest.approx(1.0, abs=0.01)


def test_the_video_can_be_decimated(made: Path, tmp_path: Path) -> None:
    ds = open_dataset(made)
    run = _run(ds, tmp_path, _double(ds), start_s=1.0, duration_s=1.0, video_every=3)
    video = cv2.VideoCapture(str(run.run_dir / "tracks.mp4"))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == 7  # frames 0, 3, ..., 18 of 21
    assert video.get(cv2.CAP_PROP_FPS) == pytest.approx(20.0 / 3, abs=0.01)
    video.release()


def _copy(made: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "copy"
    shutil.copytree(made, dst)
    return dst


def test_corrupt_image_is_rejected_counted_and_the_run_goes_on(made: Path, tmp_path: Path) -> None:
    root = _copy(made, tmp_path)
    pngs = sorted((root / "mav0" / "cam0" / "data").glob("*.png"))
    pngs[30].write_bytes(b"not a png")
    ds = open_dataset(root)
    run = _run(ds, tmp_path / "runs", _double(ds, init_after_s=0.0))
    assert run.metrics.rejected_images == 1
    assert run.metrics.frames == len(pngs) and run.metrics.frames_with_estimate == len(pngs) - 1
    lines = [json.loads(x) for x in (run.run_dir / "events.jsonl").read_text().splitlines()]
    assert [x["kind"] for x in lines].count("rejected_image") == 1
    assert read_run_status(run.run_dir) == "complete"


def test_no_ground_truth_gives_na_metrics_and_a_complete_run(made: Path, tmp_path: Path) -> None:
    root = _copy(made, tmp_path)
    ds_truth = open_dataset(root)
    shutil.rmtree(root / "mav0" / "state_groundtruth_estimate0")
    ds = open_dataset(root)
    assert ds.groundtruth is None
    double = _double(ds_truth)
    run = _run(ds, tmp_path / "runs", double)
    assert is_na(run.metrics.ape_4dof) and "no ground truth" in str(run.metrics.ape_4dof)
    assert not (run.run_dir / "groundtruth.tum").exists()
    assert (run.run_dir / "plots" / "trajectory.png").is_file()
    assert read_run_status(run.run_dir) == "complete"


def test_interrupted_run_is_not_marked_complete(made: Path, tmp_path: Path) -> None:
    ds = open_dataset(made)
    with pytest.raises(KeyboardInterrupt):
        _run(ds, tmp_path, _double(ds, init_after_s=0.0, interrupt_at_frame=20))
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    assert read_run_status(run_dir) == "interrupted"
    assert len(read_tum(run_dir / "estimate.tum")) == 20  # what was estimated is kept


def test_a_plot_on_a_full_disk_is_one_error_and_the_run_failed(
    made: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 21, item 8: matplotlib's (PIL's) OSError escaped as a traceback."""
    from matplotlib.figure import Figure

    def full(self: Figure, *a: object, **kw: object) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(Figure, "savefig", full)
    ds = open_dataset(made)
    with pytest.raises(IoError, match=r"cannot write .*plots: No space left on device"):
        _run(ds, tmp_path, _double(ds), video=False)
    (run_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    assert read_run_status(run_dir) == "failed"


def test_a_built_in_sequence_is_made_once_per_seed(made: Path) -> None:
    cache = made.parent.parent
    assert made == dataset_cache_folder(cache, "room_easy", "euroc_mono", 0, SECONDS)
    stamp = (made / "dataset.json").stat().st_mtime_ns
    again = resolve_dataset("room_easy", seed=0, duration_s=SECONDS, cache_root=cache)
    assert again.root == made and (made / "dataset.json").stat().st_mtime_ns == stamp


def test_unknown_dataset_names_the_option() -> None:
    with pytest.raises(IoError, match=r"DATASET 'room_eazy'.*room_easy"):
        resolve_dataset("room_eazy")
    with pytest.raises(IoError, match="DATASET"):
        resolve_dataset("/no/such/folder")


class _Settings(ConfigModel):
    tracker: TrackerConfig = Field(default_factory=TrackerConfig)
    g_norm: float = 9.81
    td_s: float = 0.0
    estimate_td: bool = False
    window_keyframes: int = 10


def test_vins_yaml_gives_the_rig_and_the_settings(tmp_path: Path) -> None:
    from quadnav.rig import rig_named

    path = tmp_path / "euroc_config.yaml"
    path.write_text(EUROC_LIKE)
    dataset_rig: Rig = rig_named("euroc_mono")
    cfg, rig = resolve_vio_config(_Settings, path, ["window_keyframes=7"], dataset_rig)
    assert (cfg.g_norm, cfg.td_s, cfg.estimate_td, cfg.window_keyframes) == (
        9.81007,
        0.004,
        True,
        7,
    )
    assert cfg.tracker.equalize and cfg.tracker.max_features == 150
    assert rig.cameras[0].camera.K[0, 0] == pytest.approx(458.654)
    _, rig1 = resolve_vio_config(_Settings, path, [], dataset_rig, camera="cam1")
    assert rig1.camera_names == ["cam1"]  # the file describes the camera the run uses


def test_own_yaml_refuses_an_unknown_key(tmp_path: Path) -> None:
    from quadnav.rig import rig_named

    path = tmp_path / "vio.yaml"
    path.write_text("window_keyframes: 8\nwindow_size: 3\n")
    with pytest.raises(ConfigError, match="window_size: unknown key"):
        resolve_vio_config(_Settings, path, [], rig_named("euroc_mono"))
    with pytest.raises(ConfigError, match="--config"):
        resolve_vio_config(_Settings, tmp_path / "none.yaml", [], rig_named("euroc_mono"))


def test_a_rig_without_imu_noise_is_refused_naming_the_options() -> None:
    """A bag without its calibration gives no IMU noise (and an identity extrinsic): VIO on it
    would fail in the solver (it did: 'indeterminate linear system' three times in 3 s)."""
    import dataclasses

    from quadnav.experiments.vio_run import check_vio_rig
    from quadnav.rig import ImuNoiseModel, rig_named

    rig = rig_named("euroc_mono")
    check_vio_rig(rig, "data/V1_01")  # EuRoC's own noise: accepted
    assert rig.imu is not None
    blank = dataclasses.replace(
        rig,
        imu=dataclasses.replace(
            rig.imu,
            noise=ImuNoiseModel(
                gyro_noise_density=0, gyro_random_walk=0, accel_noise_density=0, accel_random_walk=0
            ),
        ),
    )
    with pytest.raises(ConfigError, match=r"DATASET run\.bag: .*--calibration .*--config"):
        check_vio_rig(blank, "run.bag")


def test_unknown_camera_names_the_option(made: Path, tmp_path: Path) -> None:
    ds = open_dataset(made)
    with pytest.raises(ConfigError, match="--camera 'cam1'"):
        _run(ds, tmp_path, _double(ds), camera="cam1")
    assert not any(tmp_path.iterdir())  # refused before any folder was made


def test_seeds_parse_as_ranges_and_lists() -> None:
    assert parse_seeds("0-4") == (0, 1, 2, 3, 4)
    assert parse_seeds("0,2,7") == (0, 2, 7) and parse_seeds("3") == (3,)
    for bad in ("4-1", "a", "1,1", "-2", ""):
        with pytest.raises(ConfigError, match="--seeds"):
            parse_seeds(bad)


def test_a_folder_groups_by_its_name_without_the_seed() -> None:
    assert group_of("/work/data/v102_s3") == "v102" and group_of("room_easy") == "room_easy"


def test_study_over_seeds_and_folders(made: Path, tmp_path: Path) -> None:
    """Two sources: a "sequence" run for seeds 0-2 (the double's seed differs, so the ATEs
    differ) and a folder, run once whatever the seeds."""
    ds = open_dataset(made)
    assert ds.groundtruth is not None
    runs: list[OdometryRun] = []

    def run_one(source: str, seed: int, where: Path) -> OdometryRun:
        double = TruthPlusNoise(ds.groundtruth.trajectory, seed=seed, init_after_s=0.0)  # type: ignore[union-attr]
        runs.append(
            run_odometry(
                ds,
                ds.rig,
                lambda rig: double,
                where,
                options=OdometryRunOptions(video=False),
                name=f"{source}_{seed}",
            )
        )
        return runs[-1]

    with run_guard():
        study = run_odometry_study(
            ["seq", str(made)], (0, 1, 2), run_one, tmp_path, is_sequence=lambda s: s == "seq"
        )
    assert [(r.group, r.seed) for r in study.rows] == [
        ("seq", 0), ("seq", 1), ("seq", 2), (made.name, None),
    ]  # fmt: skip
    ates = [r.metrics.ape_4dof.rmse_m for r in runs if isinstance(r.metrics.ape_4dof, ApeSummary)]
    assert len(set(ates[:3])) == 3  # three seeds, three noise draws
    assert ates[3] == ates[0]  # a folder runs once, with the default seed 0
    seq = study.groups[0]
    assert seq.group == "seq" and seq.runs == 3
    assert seq.ate_mean_m == pytest.approx(np.mean(ates[:3]))
    assert seq.ate_median_m == pytest.approx(np.median(ates[:3]))
    assert study.groups[1].runs == 1
    # the double gives no final trajectory: its column says why, the group's mean too
    assert all(str(r.final_ape_se3_m).startswith("n/a") for r in study.rows)
    assert str(seq.final_ape_se3_mean_m).startswith("n/a")
    d = study.run_dir
    assert read_run_status(d) == "complete"
    assert all(r.run_dir.parent == d / "runs" for r in runs)
    saved = json.loads((d / "summary.json").read_text())
    assert [g["runs"] for g in saved["groups"]] == [3, 1]
    assert len((d / "runs.jsonl").read_text().splitlines()) == 4
    md = (d / "summary.md").read_text()
    assert f"{seq.ate_mean_m:.3f}" in md and "| seq | 3 |" in md


EUROC_MICRO = SHARED / "euroc_micro"


@needs(EUROC_MICRO)
def test_the_run_spans_the_images_with_a_second_of_imu_before(tmp_path: Path) -> None:
    """euroc_micro's IMU runs 146 s, its images 4.7 s of it: the run feeds the images and the
    IMU from 1 s before the first, not the IMU of the whole sequence; its ground truth is
    scored on the images' span."""
    ds = open_dataset(EUROC_MICRO)
    frames = ds.frames_of("cam0")
    double = _double(ds, init_after_s=0.0)
    run = _run(ds, tmp_path, double, video=False)
    span_s = (frames[-1].t_ns - frames[0].t_ns) * 1e-9
    imu = ds.imu.t_ns
    fed = np.sum((imu >= frames[0].t_ns - 1_000_000_000) & (imu <= frames[-1].t_ns))
    assert double.imu == fed and double.imu < (span_s + 1.0) * 200 + 2
    assert run.metrics.frames == len(frames)
    gt = read_tum(run.run_dir / "groundtruth.tum")
    assert gt.t_ns[0] >= frames[0].t_ns and gt.t_ns[-1] <= frames[-1].t_ns


@needs(EUROC_MICRO)
def test_only_the_used_cameras_rejected_images_are_noted(tmp_path: Path) -> None:
    """Issue 21, item 14: euroc_micro lacks 4 images of cam1; a run on cam0 noted them."""
    ds = open_dataset(EUROC_MICRO)
    assert ds.issues.counts == {"missing images": 4}
    run = _run(ds, tmp_path, _double(ds, init_after_s=0.0), video=False)
    assert not any("missing images" in n for n in run.notes)
    saved = json.loads((run.run_dir / "metrics.json").read_text())
    assert not any("missing images" in n for n in saved["notes"])


def test_bad_imu_rows_are_noted_and_the_run_goes_on(made: Path, tmp_path: Path) -> None:
    """Issue 21, item 7: one bad IMU row refused the whole dataset."""
    root = _copy(made, tmp_path)
    imu = root / "mav0" / "imu0" / "data.csv"
    lines = imu.read_text().splitlines()
    lines[100] = lines[99]  # a repeated row
    lines[200] = "not,a,row"
    imu.write_text("\n".join(lines) + "\n")
    ds = open_dataset(root)
    run = _run(ds, tmp_path / "runs", _double(ds, init_after_s=0.0), video=False)
    assert read_run_status(run.run_dir) == "complete"
    (note,) = run.notes
    assert "1 IMU rows repeated" in note and "1 IMU rows unreadable" in note


class _Calibrating(TruthPlusNoise):
    """The double, refining its calibration: cam0 turned 0.5 degrees about its optical axis,
    its focal lengths 1 % and 2 % long, its principal point 1.5 px right, its clock 3 ms on."""

    def calibration(self) -> tuple[CameraCalibration, ...]:
        told = self.rig.camera("cam0")
        turn = Pose(Rotation.from_euler("z", 0.5, degrees=True), np.zeros(3))
        K = told.camera.K
        return (
            CameraCalibration(
                camera="cam0", T_B_C=told.T_B_C @ turn, fx=K[0, 0] * 1.01, fy=K[1, 1] * 1.02,
                cx=K[0, 2] + 1.5, cy=K[1, 2], time_offset_s=told.time_offset_ns * 1e-9 + 0.003,
                sigma_rotation_deg=(0.1, 0.2, 0.3), sigma_translation_m=(0.001, 0.002, 0.003),
                sigma_intrinsics_px=(1.0, 2.0, 3.0, 4.0), sigma_time_offset_s=None,
            ),
        )  # fmt: skip


def _with_truth(made: Path, root: Path) -> Path:
    """``made`` (linked) with a ``truth/`` whose cam0 has a focal length 1 % shorter in x than
    its stated one."""
    root.mkdir()
    for p in made.iterdir():
        if p.name != "truth":  # (its own, the same as the stated: ideal sensors)
            (root / p.name).symlink_to(p)
    truth = root / "truth" / "mav0"
    for sensor in ("cam0", "imu0"):
        (truth / sensor).mkdir(parents=True)
        text = (made / "mav0" / sensor / "sensor.yaml").read_text()
        if sensor == "cam0":
            m = re.search(r"intrinsics: \[([-0-9.e+]+),", text)
            assert m is not None
            text = text[: m.start(1)] + repr(float(m.group(1)) * 0.99) + text[m.end(1) :]
        (truth / sensor / "sensor.yaml").write_text(text)
    return root


def test_an_online_calibration_is_written_against_the_stated_one_and_the_truth(
    made: Path, tmp_path: Path
) -> None:
    """calibration.json: the estimate, the stated calibration and how far apart they are; with
    the dataset's truth/, each against the truth. An odometry that does not calibrate writes
    none."""
    ds = open_dataset(_with_truth(made, tmp_path / "ds"))
    double = _Calibrating(ds.groundtruth.trajectory)  # type: ignore[union-attr]
    double.rig = ds.rig  # type: ignore[attr-defined]
    run = _run(ds, tmp_path / "out", double)
    cal = json.loads((run.run_dir / "calibration.json").read_text())
    (cam,) = cal["cameras"]
    moved = cam["estimated_minus_stated"]
    assert moved["rotation_deg"] == pytest.approx(0.5, abs=1e-9)
    assert moved["translation_m"] == pytest.approx(0.0, abs=1e-12)  # turned about its centre
    assert (moved["fx_rel"], moved["fy_rel"]) == pytest.approx((0.01, 0.02))
    assert (moved["cx_px"], moved["cy_px"], moved["time_offset_ms"]) == pytest.approx((1.5, 0, 3))
    # the truth's fx is 0.99 of the stated one: stated 1/0.99 - 1 long, estimated 1.01/0.99 - 1
    assert cam["stated_minus_truth"]["fx_rel"] == pytest.approx(1 / 0.99 - 1)
    assert cam["estimated_minus_truth"]["fx_rel"] == pytest.approx(1.01 / 0.99 - 1)
    assert cam["stated_minus_truth"]["rotation_deg"] == pytest.approx(0.0, abs=1e-6)
    assert cam["truth"]["intrinsics"][0] == pytest.approx(0.99 * cam["stated"]["intrinsics"][0])
    assert cam["estimated_sigma"] == {
        "rotation_deg": [0.1, 0.2, 0.3], "translation_m": [0.001, 0.002, 0.003],
        "intrinsics": [1.0, 2.0, 3.0, 4.0], "time_offset_ms": None,
    }  # fmt: skip
    # the same as a camchain a later run takes with --calibration: it states the estimate
    again = open_dataset(ds.root, calibration=run.run_dir / "camchain_online.yaml").rig
    est = double.calibration()[0]
    cam0 = again.camera("cam0")
    np.testing.assert_allclose(cam0.camera.K[[0, 1, 0, 1], [0, 1, 2, 2]],
                               [est.fx, est.fy, est.cx, est.cy], rtol=1e-9)  # fmt: skip
    turn = est.T_B_C.inverse() @ cam0.T_B_C
    assert np.degrees(turn.R_A_B.magnitude()) < 1e-6 and np.linalg.norm(turn.p_A_B) < 1e-9
    assert cam0.time_offset_ns * 1e-9 == pytest.approx(est.time_offset_s, abs=1e-9)
    np.testing.assert_allclose(cam0.camera.dist, ds.rig.camera("cam0").camera.dist)
    plain = _run(ds, tmp_path / "plain", _double(ds))
    assert not (plain.run_dir / "calibration.json").exists()
    assert not (plain.run_dir / "camchain_online.yaml").exists()


def test_loop_closure_passes_its_odometrys_online_calibration_through(made: Path) -> None:
    """Wrapped in loop closure, a calibrating odometry's calibration is still read (so a
    --loop run writes calibration.json); an odometry that calibrates nothing gives none."""
    from quadnav.loop import LoopClosure, LoopConfig

    ds = open_dataset(made)
    double = _Calibrating(ds.groundtruth.trajectory)  # type: ignore[union-attr]
    double.rig = ds.rig  # type: ignore[attr-defined]
    config = LoopConfig(executor="inline")
    loop = LoopClosure(double, ds.rig.camera("cam0"), config=config)
    try:
        (got,), (want,) = loop.calibration(), double.calibration()
        assert (got.camera, got.fx, got.fy, got.cx, got.cy, got.time_offset_s) == (
            want.camera, want.fx, want.fy, want.cx, want.cy, want.time_offset_s,
        )  # fmt: skip
        np.testing.assert_allclose(got.T_B_C.R_A_B.as_matrix(), want.T_B_C.R_A_B.as_matrix())
    finally:
        loop.close()
    plain = LoopClosure(_double(ds), ds.rig.camera("cam0"), config=config)
    try:
        assert plain.calibration() == ()
    finally:
        plain.close()
