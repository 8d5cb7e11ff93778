"""``quadnav slam``: bad options are one line naming the option, before anything is made."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from quadnav.cli.main import app


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--rig", "euroc_mono"], "--rig euroc_mono: one camera and no depth; the SLAM needs"),
        (["--rig", "nope"], "--rig:"),
        (["--features", "10"], "--features"),
        (["--th-depth", "0"], "--th-depth"),
        (["--duration", "-1"], "--duration"),
        (["--localization-only"], "--localization-only: give the map to localize in"),
        (["--load-map", "m", "--save-map", "m"], "--save-map m: the map loaded"),
        (["--blackout", "3"], "--blackout '3': give START:SECONDS"),
        (
            ["--calibration", "nowhere/camchain.yaml"],
            "--calibration nowhere/camchain.yaml: no such",
        ),
    ],
)
def test_a_bad_option_is_one_line(tmp_path: Path, args: list[str], named: str) -> None:
    out = tmp_path / "runs"
    result = CliRunner().invoke(app, ["slam", "room_easy", *args, "--out", str(out)])
    assert result.exit_code == 2, result.output
    text = result.output.strip()
    assert "Traceback" not in text and len(text.splitlines()) == 1, text
    assert named in text
    assert not out.exists()  # (nothing made)


def test_an_out_that_is_a_file_is_refused(tmp_path: Path) -> None:
    f = tmp_path / "file"
    f.write_text("x")
    result = CliRunner().invoke(app, ["slam", "room_easy", "--out", str(f)])
    assert result.exit_code == 2 and "is a file, not a folder" in result.output


@pytest.mark.parametrize(
    ("make", "named"),
    [
        (lambda d: None, "no such folder"),
        (lambda d: (d.mkdir(), (d / "map.json").write_text("{")), "map.json is corrupt"),
        (
            lambda d: (d.mkdir(), (d / "map.json").write_text('{"format": "quadnav-loop-map"}')),
            "not a quadnav map of this kind (quadnav-slam-map",
        ),
    ],
)
def test_a_bad_map_is_one_line_before_any_dataset_is_made(
    tmp_path: Path, make: object, named: str
) -> None:
    out, folder = tmp_path / "runs", tmp_path / "map"
    make(folder)  # type: ignore[operator]
    result = CliRunner().invoke(
        app, ["slam", "room_easy", "--load-map", str(folder), "--out", str(out)]
    )
    assert result.exit_code == 2, result.output
    text = result.output.strip()
    assert len(text.splitlines()) == 1 and "--load-map" in text and named in text, text
    assert not (out / "datasets").exists()


def test_a_serial_port_that_cannot_be_opened_is_one_line_before_anything_is_made(
    tmp_path: Path,
) -> None:
    out = tmp_path / "runs"
    port = str(tmp_path / "no_such_tty")
    result = CliRunner().invoke(app, ["slam", "room_easy", "--serial", port, "--out", str(out)])
    assert result.exit_code == 2, result.output
    text = result.output.strip()
    assert len(text.splitlines()) == 1 and f"serial port {port}" in text, text
    assert not out.exists()
