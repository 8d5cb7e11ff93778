"""Every bad input to a command is one line on stderr naming the user's own option or key,
exit code 2, no traceback and none of quadnav's class names (issue 12, item 24).

Each case is an input a user can type; the messages it gave before are in the report of the
branch that added this file. `quadnav eval` is covered by its own tests."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from quadnav.cli.main import app

runner = CliRunner()


def _our_class_names() -> set[str]:
    """Every class quadnav defines (``IntegratingImu``, ``GpsSample``, ``NavScenario``...)."""
    import quadnav

    names = set()
    for info in pkgutil.walk_packages(quadnav.__path__, "quadnav."):
        if info.name.endswith("__main__"):
            continue
        module = importlib.import_module(info.name)
        names |= {n for n, v in vars(module).items() if inspect.isclass(v) and v.__module__ == info.name}  # fmt: skip
    return names


OURS = _our_class_names()
LIBRARY_LEAKS = ("<class", "Traceback", "FileStorage", "cv2.error", "SystemError")


def _files(root: Path) -> dict[str, Path]:
    """Bad files as a user might pass them, and one image to be a source."""
    files = {
        "corrupt_ocv": "%YAML:1.0\ncamera_matrix: [1, 2\n",
        "text": "hello world\n",
        "empty": "",
        "cam_2x2": "%YAML:1.0\ncamera_matrix: !!opencv-matrix\n  rows: 2\n  cols: 2\n  dt: d\n"
        "  data: [1, 0, 0, 1]\ndistortion_coefficients: !!opencv-matrix\n  rows: 1\n  cols: 5\n"
        "  dt: d\n  data: [0, 0, 0, 0, 0]\n",
        "cam_dist_text": "%YAML:1.0\ncamera_matrix: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n"
        "  data: [500, 0, 320, 0, 500, 240, 0, 0, 1]\ndistortion_coefficients: none\n",
        "thesis_bad": "%YAML:1.0\nfps: 30\nmarker_length: abc\n",
        "tum": "0 0 0 0 0 0 0 1\n1 1 1 1 0 0 0 1\n",
    }
    out = {}
    for name, text in files.items():
        out[name] = root / f"{name}.yml"
        out[name].write_text(text)
    out["garbage"] = root / "garbage.bin"
    out["garbage"].write_bytes(bytes(range(256)) * 4)
    out["folder"] = root / "images"
    out["folder"].mkdir()
    return out


def _cal(root: Path) -> Path:
    from quadnav.geometry.camera import thesis_camera
    from quadnav.io.opencv_yaml import write_camera_yaml

    path = root / "cal.yml"
    write_camera_yaml(path, thesis_camera())
    return path


RUN = ["run", "--jobs", "1", "--set", "vision.source=pose"]
SIM = ["sim"]
PLANAR = ["planar", "--jobs", "1"]
MARKERS = ["markers", "{folder}", "--camera", "{cal}"]

# (command line, what the message must name). {name} is one of the files above; {out} the
# run folder root. Each of these gave a traceback, a class name, a wrong cause or a key the
# user never wrote before this file was added.
# fmt: off
CASES: list[tuple[list[str], str]] = [
    # quadnav run: sensor rates so slow their period overflows, or no sample is ever taken
    ([*RUN, "--set", "imu.rate_hz=1e-300"], "imu.rate_hz"),
    ([*RUN, "--set", "imu.rate_hz=0.01"], "estimator.align_s"),
    ([*RUN, "--set", "baro.rate_hz=1e-300"], "baro.rate_hz"),
    ([*RUN, "--set", "vision.rate_hz=1e-300"], "vision.rate_hz"),
    ([*RUN, "--set", "imu.rate_hz=1000"], "sim_dt_s"),
    ([*RUN, "--set", "range.enabled=true", "--set", "range.max_m=0.01"], "range.max_m"),
    ([*RUN, "--set", "sim_dt_s=1e-12"], "sim_dt_s"),
    ([*RUN, "--set", "vision.sigma_m=1e-300"], "vision.sigma_m"),
    ([*RUN, "--set", "gps.enabled=true", "--set", "gps.sigma_h_m=1e-300"], "gps.sigma_h_m"),
    # quadnav sim
    ([*SIM, "--set", "mass_kg=100"], "mass_kg"),
    ([*SIM, "--set", "mass_kg=1e-300"], "mass_kg"),
    ([*SIM, "--set", "dt_s=1e-12"], "dt_s"),
    ([*SIM, "--set", "log_rate_hz=1e-300"], "log_rate_hz"),
    ([*SIM, "--set", "pid_gains.kp_pos=-1"], "pid_gains.kp_pos"),
    ([*SIM, "--set", "pid_gains.kp_pos=[1,1,-1]"], "pid_gains"),
    ([*SIM, "thesis002_pd_tracking", "--set", "el_pd.kp_z=-1"], "el_pd"),
    ([*SIM, "thesis002_pd_tracking", "--set", "mass_kg=1e-300"], "mass_kg"),
    ([*SIM, "thesis002_nested_tracking", "--set", "el_nested.levels_rad_s2=[1,2]"], "el_nested.levels_rad_s2"),
    ([*SIM, "--set", "world=[{{min_m: [1,1,1], max_m: [0,0,0]}}]"], "world.0.min_m"),
    # quadnav planar
    ([*PLANAR, "--set", "dt_s=1e-6", "--set", "duration_s=3600", "--set", "gps.period_s=1"], "dt_s"),
    ([*PLANAR, "--set", "vehicle.mass_kg=1e-300"], "vehicle.mass_kg"),
    ([*PLANAR, "--set", "gps.sigma_m=1e-300"], "gps.sigma_m"),
    ([*PLANAR, "--set", "estimator.init_sigma_pos_m=1e-300"], "estimator.init_sigma_pos_m"),
    ([*PLANAR, "--set", "estimator.max_delay_s=10", "--set", "duration_s=2"], "estimator.max_delay_s"),
    ([*PLANAR, "--set", "vehicle.inertia_kg_m2=1e-300"], "vehicle."),
    # quadnav calibrate
    (["calibrate", "{folder}", "--square-m", "-1"], "--square-m must be positive"),
    (["calibrate", "{folder}", "--square-m", "0"], "--square-m must be positive"),
    (["calibrate", "{folder}", "--marker-m", "-1"], "--marker-m must be positive"),
    (["calibrate", "{folder}", "--square-m", "nan"], "--square-m"),
    (["calibrate", "{folder}", "--square-m", "inf"], "--square-m"),
    (["calibrate", "{folder}", "--marker-m", "0.05"], "--marker-m (0.05 m) must be smaller than --square-m"),
    (["calibrate", "{folder}", "--squares", "1", "7"], "--squares"),
    (["calibrate", "{folder}", "--squares", "100000", "100000"], "--squares"),
    (["calibrate", "{folder}", "--dictionary", "NOPE"], "--dictionary"),
    (["calibrate", "{folder}", "--out", "{folder}/no/such/cal.yml"], "--out"),
    # quadnav markers: corrupt, non-YAML and wrong calibration and parameter files
    (["markers", "{folder}", "--camera", "{corrupt_ocv}"], "line 2: missing , between the elements"),
    (["markers", "{folder}", "--camera", "{garbage}"], "garbage.bin: not an OpenCV YAML/XML file"),
    (["markers", "{folder}", "--camera", "{text}"], "text.yml: not an OpenCV YAML/XML file"),
    (["markers", "{folder}", "--camera", "{empty}"], "empty.yml: not an OpenCV YAML/XML file (the file is empty)"),
    (["markers", "{folder}", "--camera", "{cam_2x2}"], "camera_matrix must be a 3x3 matrix"),
    (["markers", "{folder}", "--camera", "{cam_dist_text}"], "distortion_coefficients must be a matrix, got 'none'"),
    (["markers", "{folder}", "--camera", "{folder}"], "--camera"),
    (["markers", "{folder}", "--params", "{thesis_bad}"], "marker_length"),
    (["markers", "{folder}", "--set", "camera_file={garbage}"], "garbage.bin: not an OpenCV"),
    ([*MARKERS, "--set", "detector_file={corrupt_ocv}"], "corrupt_ocv.yml: not an OpenCV"),
    ([*MARKERS, "--set", "detector.adaptiveThreshWinSizeMin=-5"], "detector"),
    ([*MARKERS, "--set", "dictionary=NOPE"], "dictionary"),
    ([*MARKERS, "--set", "marker_id=100000"], "marker_id"),
    ([*MARKERS, "--set", "target=charuco", "--set", "charuco.squares_x=100000", "--set", "charuco.squares_y=100000"], "charuco.squares_x"),
    # quadnav link serial
    (["link", "serial", "{text}", "--from", "{garbage}"], "--from: "),
    (["link", "serial", "{text}", "--from", "{garbage}", "--format", "nope"], "--format must be one of"),
    (["link", "serial", "/dev/no_such_port", "--from", "{tum}"], "serial port /dev/no_such_port: No such file"),
]
# fmt: on


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("bad_inputs")
    out = _files(root)
    out["cal"] = _cal(root)
    return out


@pytest.mark.parametrize(("args", "named"), CASES, ids=[" ".join(a) for a, _ in CASES])
def test_bad_input_is_one_line_naming_the_users_option(
    args: list[str], named: str, files: dict[str, Path], tmp_path: Path
) -> None:
    argv = [a.format(**{k: str(v) for k, v in files.items()}) for a in args]
    if argv[0] in ("run", "sim", "planar", "markers"):
        argv += ["--out", str(tmp_path / "runs")]
    result = runner.invoke(app, argv)
    lines = result.stderr.strip().splitlines()
    assert result.exit_code == 2, (result.exit_code, result.output, result.exception)
    assert len(lines) == 1, lines
    assert "Traceback" not in result.output
    assert named.format(**{k: str(v) for k, v in files.items()}) in lines[0], lines[0]
    words = set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", lines[0]))
    assert not words & OURS, f"names our classes {words & OURS}: {lines[0]}"
    assert not any(leak in lines[0] for leak in LIBRARY_LEAKS), lines[0]
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())
