"""Every command's help is made from its registries, and every example in every ``--help``
parses and validates (issue 12, item 23)."""

from __future__ import annotations

import importlib
import re
import shlex
from pathlib import Path
from typing import Any

import pytest
import typer
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.experiments.flight import BUILTIN, BUILTIN_DESCRIPTIONS
from quadnav.experiments.scenarios import NAV_SCENARIOS
from tests.shared_data import SHARED

ROOT = Path(__file__).resolve().parents[2]

#: command path -> the module that holds its EXAMPLES and check_example
COMMANDS = {
    ("run",): "quadnav.cli.run",
    ("sweep",): "quadnav.cli.sweep",
    ("planar",): "quadnav.cli.planar",
    ("sim",): "quadnav.cli.sim",
    ("link", "serial"): "quadnav.cli.link",
    ("replay",): "quadnav.cli.replay",
    ("eval",): "quadnav.cli.eval",
    ("markers",): "quadnav.cli.markers",
    ("calibrate",): "quadnav.cli.calibrate",
    ("dataset", "make"): "quadnav.cli.dataset",
    ("vio",): "quadnav.cli.vio",
    ("slam",): "quadnav.cli.slam",
    ("view",): "quadnav.cli.view",
}


def _command(path: tuple[str, ...]) -> Any:
    """The click command of ``quadnav <path>`` (typer bundles its own click)."""
    cmd: Any = typer.main.get_command(app)
    for name in path:
        cmd = cmd.commands[name]
    return cmd


def _examples() -> list[tuple[tuple[str, ...], str]]:
    return [
        (path, example)
        for path, module in COMMANDS.items()
        for example in importlib.import_module(module).EXAMPLES
    ]


@pytest.mark.parametrize(("path", "example"), _examples(), ids=lambda x: str(x))
def test_every_example_parses_and_validates(
    path: tuple[str, ...], example: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    if "../shared/data" in example and not SHARED.is_dir():
        pytest.skip(f"shared test data not found at {SHARED}")
    monkeypatch.chdir(ROOT)  # the examples name ../shared/data from the project folder
    argv = shlex.split(example)
    assert argv[: 1 + len(path)] == ["quadnav", *path], example
    cmd = _command(path)
    ctx = cmd.make_context(" ".join(path), argv[1 + len(path) :])  # a bad option raises here
    importlib.import_module(COMMANDS[path]).check_example(ctx.params)


def test_the_set_options_own_example_names_a_real_key(monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 21, item 14: ``vio --help`` offered ``--set gps.delay_s=0.5``, a key of the
    navigation filter's. An example in the help of ``--set`` itself is validated as the
    command's examples are: after the command's first example. (Most commands' ``--set`` help
    names no key; vio's names one of its own.)"""
    monkeypatch.chdir(ROOT)
    checked = []
    for path, name in COMMANDS.items():
        cmd = _command(path)
        helps = [p.help or "" for p in cmd.params if "--set" in getattr(p, "opts", ())]
        module = importlib.import_module(name)
        for shown in (m for h in helps for m in re.findall(r"e\.g\. (--set \S+)", h)):
            argv = shlex.split(module.EXAMPLES[0])[1 + len(path) :] + shlex.split(shown)
            if any("../shared/data" in a for a in argv) and not SHARED.is_dir():
                argv = shlex.split(shown)  # the example's data is absent: the key alone
            module.check_example(cmd.make_context(" ".join(path), argv).params)
            checked.append((path, shown))
    assert ("vio",) in {path for path, _ in checked}, checked


def test_every_command_has_examples() -> None:
    from quadnav.cli.main import COMMANDS as ALL

    covered = {path[0] for path in COMMANDS}
    assert covered == set(ALL), f"commands without validated examples: {set(ALL) - covered}"


@pytest.mark.parametrize("path", list(COMMANDS), ids=" ".join)
def test_the_help_shows_every_example(path: tuple[str, ...]) -> None:
    result = CliRunner().invoke(app, [*path, "--help"], env={"COLUMNS": "400"})
    assert result.exit_code == 0
    text = " ".join(result.stdout.split())
    examples = importlib.import_module(COMMANDS[path]).EXAMPLES
    assert examples, f"{path} has no examples"
    for example in examples:
        assert " ".join(example.split()) in text


def test_run_help_lists_every_scenario_and_describes_the_camera_default() -> None:
    result = CliRunner().invoke(app, ["run", "--help"], env={"COLUMNS": "400"})
    text = " ".join(result.stdout.split())
    for name in [*NAV_SCENARIOS, "planar"]:
        assert f"{name}:" in text
    assert "renders a downward camera" in text
    assert "pose shortcut" in text.split("indoor_vision_pose:")[1].split("indoor_vision_truth")[0]


def test_sim_scenarios_all_have_a_description() -> None:
    assert set(BUILTIN) == set(BUILTIN_DESCRIPTIONS)
    result = CliRunner().invoke(app, ["sim", "--help"], env={"COLUMNS": "400"})
    text = " ".join(result.stdout.split())
    assert all(f"{name}:" in text for name in BUILTIN)


def test_a_bad_example_would_be_caught() -> None:
    # the checker itself: an unknown key and an unknown option are both refused
    from quadnav.cli import run
    from quadnav.errors import ConfigError

    with pytest.raises(ConfigError, match=r"plan\.sqare_m: unknown key"):
        run.check_example({"scenario": None, "set_": ["plan.sqare_m=2"], "seeds": None})
    with pytest.raises(Exception, match="No such option"):
        _command(("run",)).make_context("run", ["--sed", "3"])


def test_an_example_checker_reads_each_parameter_as_its_type() -> None:
    """check_example takes click's parsed parameters: each one is read as the command's type,
    so a checker handed the wrong shape says which parameter, rather than validating a guess."""
    from quadnav.cli import link, replay, run

    with pytest.raises(TypeError, match="parameter scenario: 3 is not of type str"):
        run.check_example({"scenario": 3, "set_": (), "seeds": None})
    with pytest.raises(
        TypeError, match=r"parameter set_: 'gps_delay_s=0\.2' is not a list of text"
    ):
        replay.check_example({"set_": "gps_delay_s=0.2"})
    with pytest.raises(TypeError, match="parameter baud: '9600' is not of type int"):
        link.check_example({"baud": "9600", "rate_hz": 10.0, "fmt": None})
    run.check_example({"scenario": None, "set_": ("plan.square_m=2",), "seeds": 3})  # a tuple
