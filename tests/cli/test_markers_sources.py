"""`quadnav markers` on what issue 12 found: raw streams timed at the configured fps, a
calibration for another resolution, a folder of unreadable images, metrics.json, a live camera
given the thesis's settings, the window, rejected candidates and saved frames."""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.errors import ConfigError
from quadnav.experiments.markers_run import fit_calibration, load_markers_config, run_markers
from quadnav.geometry.camera import thesis_camera
from quadnav.io.frames import is_raw_stream
from quadnav.io.opencv_yaml import write_camera_yaml
from tests.cli.conftest import marker_views

runner = CliRunner()
IDENTITY_MOUNT = ["--set", "mount_rpy_deg=[0,0,0]", "--set", "video=false"]


def _markers(args: list[str], out: Path) -> tuple[Any, Path | None]:
    res = runner.invoke(app, ["markers", *args, "--out", str(out)])
    runs = sorted(out.glob("*_markers"))
    return res, runs[-1] if runs else None


def _t_ns(run: Path) -> np.ndarray:
    return np.array([int(r["t_ns"]) for r in csv.DictReader((run / "poses.csv").open())])


def _thesis_params(path: Path, **extra: object) -> Path:
    """A vision_params.yml as the thesis program reads it (OpenCV YAML)."""
    lines = ["%YAML:1.0", "dict_type: 2", "marker_length: 0.2335"]
    lines += [f"{k}: {v}" for k, v in extra.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def raw_mjpeg(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Six frames as a raw MJPEG stream (JPEGs back to back: no container, no timestamps;
    OpenCV reports 25 fps for it), and the calibration."""
    root = tmp_path_factory.mktemp("raw")
    images, _ = marker_views(thesis_camera(), 6)
    stream = root / "flight.mjpeg"
    stream.write_bytes(b"".join(cv2.imencode(".jpg", im)[1].tobytes() for im in images))
    cal = root / "cal.yml"
    write_camera_yaml(cal, thesis_camera())
    return stream, cal


def test_a_raw_stream_is_timed_at_the_configured_fps(raw_mjpeg, tmp_path: Path) -> None:
    stream, cal = raw_mjpeg
    assert is_raw_stream(stream)
    for extra, period_ns, says in (
        (["--set", "fps=40"], 25_000_000, "40 fps (fps; the stream has no timestamps)"),
        (["--fps", "20"], 50_000_000, "20 fps (fps;"),
        ([], round(1e9 / 30), "30 fps (the default; set fps or --fps"),
    ):
        res, run = _markers([str(stream), "--camera", str(cal), *IDENTITY_MOUNT, *extra], tmp_path / str(period_ns))  # fmt: skip
        assert res.exit_code == 0, res.output
        assert run is not None
        # k * 1e9 / fps rounded to whole nanoseconds
        np.testing.assert_allclose(np.diff(_t_ns(run)), period_ns, atol=1)
        stats = json.loads((run / "stats.json").read_text())
        assert says in stats["time_base"] and "time base" in res.output


def test_a_raw_h264_stream_takes_the_thesis_fps(tmp_path: Path) -> None:
    """The thesis's own case: a raw .h264 (as the Raspberry Pi camera records) with its
    vision_params.yml saying fps: 40; the overlay video is written at 40 fps too."""
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg is None:
        pytest.skip("ffmpeg is not installed: it is needed to encode a raw .h264 stream")
    images, _ = marker_views(thesis_camera(), 5)
    for k, im in enumerate(images):
        cv2.imwrite(str(tmp_path / f"f{k:03d}.png"), im)
    stream = tmp_path / "flight.h264"
    subprocess.run([ffmpeg, "-loglevel", "error", "-framerate", "40", "-i", str(tmp_path / "f%03d.png"),
                    "-c:v", "libx264", "-pix_fmt", "yuv420p", str(stream)], check=True)  # fmt: skip
    cal = tmp_path / "cal.yml"
    write_camera_yaml(cal, thesis_camera())
    params = _thesis_params(tmp_path / "vision_params.yml", fps=40)
    res, run = _markers([str(stream), "--params", str(params), "--camera", str(cal),
                         "--set", "mount_rpy_deg=[0,0,0]"], tmp_path / "out")  # fmt: skip
    assert res.exit_code == 0, res.output
    assert run is not None
    np.testing.assert_array_equal(np.diff(_t_ns(run)), 25_000_000)
    assert cv2.VideoCapture(str(run / "overlay.mp4")).get(cv2.CAP_PROP_FPS) == pytest.approx(40)


def test_a_video_with_timestamps_keeps_them(tmp_path: Path) -> None:
    images, _ = marker_views(thesis_camera(), 4)
    video = tmp_path / "flight.mp4"
    w = cv2.VideoWriter(str(video), cv2.VideoWriter.fourcc(*"mp4v"), 40, (640, 480))
    for im in images:
        w.write(cv2.cvtColor(im, cv2.COLOR_GRAY2BGR))
    w.release()
    assert not is_raw_stream(video)
    cal = tmp_path / "cal.yml"
    write_camera_yaml(cal, thesis_camera())
    res, run = _markers([str(video), "--camera", str(cal), *IDENTITY_MOUNT, "--fps", "10"], tmp_path / "out")  # fmt: skip
    assert res.exit_code == 0, res.output
    assert run is not None
    np.testing.assert_array_equal(np.diff(_t_ns(run)), 25_000_000)
    assert json.loads((run / "stats.json").read_text())["time_base"].startswith("the video's")


def test_raw_stream_sniffing(tmp_path: Path) -> None:
    cases = {
        "annexb4.h264": (b"\x00\x00\x00\x01\x67\x64", True),
        "annexb3.h265": (b"\x00\x00\x01\x40\x01", True),
        "program.mpg": (b"\x00\x00\x01\xba\x44", False),  # MPEG-PS carries timestamps
        "mjpeg.bin": (b"\xff\xd8\xff\xe0", True),
        "box.mp4": (b"\x00\x00\x00\x1cftypisom", False),
        "matroska.mkv": (b"\x1a\x45\xdf\xa3", False),
    }
    for name, (head, raw) in cases.items():
        (tmp_path / name).write_bytes(head + b"\x00" * 16)
        assert is_raw_stream(tmp_path / name) is raw, name


def test_fit_calibration_scales_or_refuses() -> None:
    cam = thesis_camera()
    same, note = fit_calibration(cam, (640, 480))
    assert same is cam and note == ""
    big, note = fit_calibration(cam, (1280, 960))
    np.testing.assert_allclose(big.K[:2], 2 * cam.K[:2])
    np.testing.assert_array_equal(big.dist, cam.dist)
    assert (big.width, big.height) == (1280, 960) and "scaled x2" in note and "640x480" in note
    with pytest.raises(ConfigError, match=r"--camera.*640x480.*799x533"):
        fit_calibration(cam, (799, 533))


def test_a_calibration_of_the_same_shape_is_scaled_and_said(tmp_path: Path) -> None:
    """Frames at 1280x960 and the 640x480 calibration of the same lens: the run says it
    scaled the calibration and the poses are as good as at the calibrated size."""
    big = thesis_camera().scaled(1280, 960)
    images, truth = marker_views(big, 4)
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, im in enumerate(images):
        cv2.imwrite(str(folder / f"f{k}.png"), im)
    cal = tmp_path / "cal.yml"
    write_camera_yaml(cal, thesis_camera())
    res, run = _markers([str(folder), "--camera", str(cal), *IDENTITY_MOUNT], tmp_path / "out")
    assert res.exit_code == 0, res.output
    assert "640x480" in res.output and "scaled x2 to the frames' 1280x960" in res.output
    assert run is not None
    rows = list(csv.DictReader((run / "poses.csv").open()))
    assert len(rows) == 4
    for r in rows:
        p = np.array([float(r["x_m"]), float(r["y_m"]), float(r["z_m"])])
        assert np.linalg.norm(p - truth[int(r["frame"])].p_A_B) < 0.02


def test_a_calibration_of_another_shape_is_refused(frames, tmp_path: Path) -> None:
    folder, cal, _ = frames
    odd = tmp_path / "odd"
    odd.mkdir()
    img = cv2.imread(str(folder / "f000.png"))
    cv2.imwrite(str(odd / "f0.png"), cv2.resize(img, (799, 533)))
    res, run = _markers([str(odd), "--camera", str(cal)], tmp_path / "out")
    assert res.exit_code == 2 and run is None
    assert "640x480" in res.output and "799x533" in res.output and "--camera" in res.output
    assert "Traceback" not in res.output and len(res.output.strip().splitlines()) == 1


def test_a_folder_of_unreadable_images_is_an_error(frames, tmp_path: Path) -> None:
    _, cal, _ = frames
    bad = tmp_path / "bad"
    bad.mkdir()
    for k in range(3):
        (bad / f"f{k}.jpg").write_bytes(b"\xff\xd8 not really a jpeg")
    res, run = _markers([str(bad), "--camera", str(cal)], tmp_path / "out")
    assert res.exit_code == 2 and run is None, res.output
    assert "none of the 3 images can be decoded" in res.output
    assert "Traceback" not in res.output and len(res.output.strip().splitlines()) == 1


def test_metrics_json_is_a_flat_mapping_of_numbers(frames, tmp_path: Path) -> None:
    folder, cal, _ = frames
    res, run = _markers([str(folder), "--camera", str(cal), *IDENTITY_MOUNT], tmp_path)
    assert res.exit_code == 0, res.output
    assert run is not None
    metrics = json.loads((run / "metrics.json").read_text())
    stats = json.loads((run / "stats.json").read_text())
    assert metrics.pop("kind") == "markers"
    assert metrics["frames"] == 10 and metrics["frames_skipped"] == 1
    assert metrics["fraction_with_pose"] == pytest.approx(0.9)
    for k, v in metrics.items():
        assert v is None or (isinstance(v, int | float) and not isinstance(v, bool)), k
        assert v == stats[k], k


class FakeCamera:
    """A V4L2 camera as OpenCV's capture object shows it: it takes a frame size and the
    exposure mode, rounds any frame rate to the 30 fps it supports and refuses a manual
    exposure time. It gives ``images`` at its current size, then stops."""

    def __init__(self, images: list[np.ndarray]) -> None:
        self.images = images
        self.props = {cv2.CAP_PROP_FRAME_WIDTH: 1280.0, cv2.CAP_PROP_FRAME_HEIGHT: 720.0,
                      cv2.CAP_PROP_FPS: 30.0, cv2.CAP_PROP_AUTO_EXPOSURE: 3.0, cv2.CAP_PROP_EXPOSURE: 166.0}  # fmt: skip
        self.calls: list[tuple[Any, ...]] = []
        self.released = False
        self.interrupt_at = -1  # the read at which the user presses Ctrl-C

    def isOpened(self) -> bool:  # OpenCV's name
        return True

    def set(self, prop: int, value: float) -> bool:
        self.calls.append(("set", prop, value))
        if prop in (
            cv2.CAP_PROP_FRAME_WIDTH,
            cv2.CAP_PROP_FRAME_HEIGHT,
            cv2.CAP_PROP_AUTO_EXPOSURE,
        ):
            self.props[prop] = value
            return True
        if prop == cv2.CAP_PROP_FPS:
            self.props[prop] = 30.0
            return True
        return False

    def get(self, prop: int) -> float:
        return self.props.get(prop, 0.0)

    def read(self) -> tuple[bool, np.ndarray | None]:
        self.calls.append(("read",))
        k = sum(c == ("read",) for c in self.calls) - 1
        if k == self.interrupt_at:
            raise KeyboardInterrupt
        if k >= len(self.images):
            return False, None
        size = (
            int(self.props[cv2.CAP_PROP_FRAME_WIDTH]),
            int(self.props[cv2.CAP_PROP_FRAME_HEIGHT]),
        )
        return True, cv2.cvtColor(cv2.resize(self.images[k], size), cv2.COLOR_GRAY2BGR)

    def release(self) -> None:
        self.released = True


def test_a_live_camera_is_given_the_thesis_settings(frames, tmp_path: Path) -> None:
    """The thesis's fps, frame size and exposure go to the camera before the first frame; the
    run says which the driver took; write_images saves each overlay frame."""
    _, cal, _ = frames
    images, _ = marker_views(thesis_camera(), 5)
    camera = FakeCamera(images)
    params = _thesis_params(tmp_path / "vision_params.yml", fps=40, frame_width=640, frame_height=480,
                            exposure_time=40, open_window="false", show_rejected="false", write_images="true")  # fmt: skip
    cfg, ignored = load_markers_config(params, [f"camera_file={cal}", "mount_rpy_deg=[0,0,0]", "video=false"])  # fmt: skip
    thesis_keys = {"fps", "frame_width", "frame_height", "exposure_time", "open_window", "show_rejected", "write_images"}  # fmt: skip
    assert not thesis_keys & set(ignored), ignored
    stats = run_markers(cfg, "0", tmp_path / "out", open_camera=lambda index: camera)
    props = {p.name: p for p in stats.camera_properties}
    assert props["frame_width_px"].accepted and props["frame_height_px"].got == 480
    assert props["fps"].requested == 40 and props["fps"].got == 30 and not props["fps"].accepted
    assert props["auto_exposure"].got == 1 and props["auto_exposure"].accepted  # manual
    assert props["exposure_time_100us"].requested == 40 and not props["exposure_time_100us"].accepted  # fmt: skip
    first_read = camera.calls.index(("read",))
    assert all(c[0] == "set" for c in camera.calls[:first_read]) and len(camera.calls[:first_read]) == 5  # fmt: skip
    assert stats.frames == stats.frames_with_pose == 5 and camera.released
    assert stats.time_base.startswith("arrival time")
    run = stats.run_dir
    assert stats.images_written == 5 and len(list((run / "images").glob("frame_*.png"))) == 5
    assert np.all(np.diff(_t_ns(run)) > 0)
    assert "camera 0 did not take fps=40 (it reports 30)" in stats.notes


def test_show_without_a_display_is_one_line(frames, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    folder, cal, _ = frames
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    quiet = _thesis_params(tmp_path / "quiet.yml", open_window="false")
    for extra in (["--show"], ["--params", str(quiet), "--show"], ["--set", "show=true"]):
        res, run = _markers([str(folder), "--camera", str(cal), *extra], tmp_path / "out")
        assert res.exit_code == 2 and run is None, res.output
        assert "--show" in res.output and "no display (DISPLAY" in res.output
        assert "Traceback" not in res.output and len(res.output.strip().splitlines()) == 1


def test_a_parameter_file_window_without_a_display_runs_on_and_says_so(frames, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """Issue 21, item 2: 4 of the thesis's 5 parameter files say open_window: true; CI and a
    companion computer have no display. The run goes on without a window, in one line."""
    folder, cal, _ = frames
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    params = _thesis_params(tmp_path / "vision_params.yml", open_window="true")
    common = [str(folder), "--camera", str(cal), "--params", str(params), *IDENTITY_MOUNT]
    res, run = _markers(common, tmp_path / "file")
    assert res.exit_code == 0 and run is not None, res.output
    said = [ln for ln in res.output.splitlines() if "no window" in ln]
    assert len(said) == 1 and "open_window" in said[0] and "no display" in said[0], said
    assert json.loads((run / "status.json").read_text())["status"] == "complete"
    res, run = _markers([*common, "--no-show"], tmp_path / "no-show")
    assert res.exit_code == 0 and run is not None and "no window" not in res.output


def test_no_show_overrides_the_file_where_there_is_a_display(frames, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    folder, cal, _ = frames
    monkeypatch.setenv("DISPLAY", ":99")
    shown: list[np.ndarray] = []
    monkeypatch.setattr(cv2, "imshow", lambda title, img: shown.append(img))
    monkeypatch.setattr(cv2, "waitKey", lambda ms: -1)
    monkeypatch.setattr(cv2, "destroyWindow", lambda title: None)
    params = _thesis_params(tmp_path / "vision_params.yml", open_window="true")
    common = [str(folder), "--camera", str(cal), "--params", str(params), *IDENTITY_MOUNT]
    res, _ = _markers([*common, "--no-show"], tmp_path / "no-show")
    assert res.exit_code == 0 and not shown, res.output
    res, _ = _markers(common, tmp_path / "file")  # a display: the file's window opens
    assert res.exit_code == 0 and len(shown) == 9, res.output


def test_show_puts_each_frame_in_a_window_and_q_stops(frames, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """With a display (the window calls faked: there is no X server here), each overlay frame
    is shown and pressing q ends the run cleanly, the frames so far written out."""
    folder, cal, _ = frames
    monkeypatch.setenv("DISPLAY", ":99")
    shown: list[np.ndarray] = []
    keys = [-1, -1, ord("q")]
    monkeypatch.setattr(cv2, "imshow", lambda title, img: shown.append(img))
    monkeypatch.setattr(cv2, "waitKey", lambda ms: keys.pop(0))
    monkeypatch.setattr(cv2, "destroyWindow", lambda title: None)
    res, run = _markers([str(folder), "--camera", str(cal), *IDENTITY_MOUNT, "--show"], tmp_path)
    assert res.exit_code == 0, res.output
    assert run is not None
    stats = json.loads((run / "stats.json").read_text())
    assert len(shown) == 3 and shown[0].shape == (480, 640, 3)
    assert (
        stats["frames"] == 3
        and stats["stopped_by"] == "window (q or Esc)"
        and stats["frames_with_pose"] == 3
    )


def test_show_rejected_draws_the_candidates_in_the_saved_frames(frames, tmp_path: Path) -> None:
    _, cal, _ = frames
    images, _ = marker_views(thesis_camera(), 3)
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, im in enumerate(images):
        # a black square with a white centre: a marker candidate no dictionary code fits
        cv2.rectangle(im, (20, 20), (120, 120), 0, -1)
        cv2.rectangle(im, (45, 45), (95, 95), 255, -1)
        cv2.imwrite(str(folder / f"f{k}.png"), im)
    pink = {}
    for flag in ("true", "false"):
        res, run = _markers([str(folder), "--camera", str(cal), *IDENTITY_MOUNT, "--set", "write_images=true",
                             "--set", f"show_rejected={flag}"], tmp_path / flag)  # fmt: skip
        assert res.exit_code == 0, res.output
        assert run is not None
        saved = sorted((run / "images").glob("frame_*.png"))
        assert [p.name for p in saved] == [
            "frame_000000.png",
            "frame_000001.png",
            "frame_000002.png",
        ]
        edge = cv2.imread(str(saved[0]))[18:23, 40:100].astype(int)  # the candidate's top edge
        pink[flag] = np.all(np.abs(edge - [100, 0, 255]) < 60, axis=2).any(axis=0).mean()
    assert pink["true"] > 0.9 and pink["false"] == 0.0


def test_ctrl_c_ends_a_live_run_with_its_results_written(frames, tmp_path: Path) -> None:
    _, cal, _ = frames
    images, _ = marker_views(thesis_camera(), 6)
    camera = FakeCamera(images)
    camera.interrupt_at = 4
    camera.props[cv2.CAP_PROP_FRAME_WIDTH], camera.props[cv2.CAP_PROP_FRAME_HEIGHT] = 640.0, 480.0
    cfg, _ = load_markers_config(None, [f"camera_file={cal}", "mount_rpy_deg=[0,0,0]"])
    stats = run_markers(cfg, "0", tmp_path, open_camera=lambda index: camera)
    assert stats.stopped_by == "interrupt (Ctrl-C)" and stats.frames_with_pose == 4
    run = stats.run_dir
    assert len(_t_ns(run)) == 4 and (run / "metrics.json").is_file()
    assert (run / "overlay.mp4").stat().st_size > 1000
    assert not [c for c in camera.calls if c[0] == "set"]  # nothing asked: the driver's settings
