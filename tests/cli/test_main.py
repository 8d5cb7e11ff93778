"""Start-up: ``quadnav --help`` loads no command, every command still lists and helps."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from quadnav.cli.main import COMMANDS, app, load_command, short_help

runner = CliRunner()
HEAVY = ("cv2", "matplotlib", "pymavlink", "pyulog", "rosbags", "scipy")

PROBE = """
import json, sys
sys.argv = ["quadnav", *sys.argv[1:]]
from quadnav.cli.main import main
try:
    main()
except SystemExit:
    pass
print(json.dumps(sorted(sys.modules)))
"""


def loaded_packages(*args: str) -> tuple[str, set[str]]:
    """The output of ``quadnav ARGS`` in a fresh interpreter, and the modules it imported."""
    proc = subprocess.run(
        [sys.executable, "-c", PROBE, *args], capture_output=True, text=True, timeout=120
    )
    out, _, last = proc.stdout.rstrip().rpartition("\n")
    names = json.loads(last)
    return out, set(names) | {m.split(".")[0] for m in names}


def test_help_imports_none_of_the_heavy_packages() -> None:
    out, loaded = loaded_packages("--help")
    assert not loaded & set(HEAVY), f"quadnav --help imported {sorted(loaded & set(HEAVY))}"
    assert "Commands:" in out
    listed = out.split("Commands:")[1]
    for name in COMMANDS:
        assert f"\n  {name} " in listed, f"{name} is not listed"


def test_eval_without_plots_loads_only_what_it_uses(tmp_path: Path) -> None:
    lines = [f"{k}.0 {k} {k % 3} {k % 5} 0 0 0 1" for k in range(10)]
    (tmp_path / "a.tum").write_text("\n".join(lines) + "\n")
    args = [str(tmp_path / "a.tum"), str(tmp_path / "a.tum"), "--align", "se3", "--no-plots"]
    out, loaded = loaded_packages("eval", *args, "--out", str(tmp_path / "runs"))
    assert "ape_trans_m" in out  # it ran
    assert "matplotlib" not in loaded and "scipy.stats" not in loaded
    assert "yaml" not in loaded and "rich.progress" not in loaded  # 0.1 s of start-up


@pytest.mark.parametrize("name", list(COMMANDS))
def test_each_command_keeps_its_one_line_help_and_its_own_help(name: str) -> None:
    real = load_command(name).help or ""
    assert short_help(name) == " ".join(real.strip().split("\n\n")[0].split())
    result = runner.invoke(app, [name, "--help"])
    assert result.exit_code == 0, result.output
    assert f"quadnav {name}" in result.output and "--help" in result.output


def test_version_prints_the_package_version() -> None:
    from typer.testing import CliRunner

    import quadnav
    from quadnav.cli.main import app

    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0
    assert result.stdout.strip() == f"quadnav {quadnav.__version__}"


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["run", "--seeds", "0"], "--seeds"),
        (["run", "--sed", "3"], "--sed"),
        (["calibrate", "x", "--every", "0"], "--every"),
        (["nosuch"], "nosuch"),
    ],
)
def test_a_usage_error_is_one_line_naming_the_option(args: list[str], named: str) -> None:
    res = subprocess.run(
        [sys.executable, "-m", "quadnav", *args], capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and named in lines[0], res.stderr


def test_quadnav_alone_shows_its_help() -> None:
    res = subprocess.run(
        [sys.executable, "-m", "quadnav"], capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 0 and "Commands:" in res.stdout and "run" in res.stdout
