"""The documentation site builds with ``mkdocs build --strict``, its navigation lists every page,
and every shell example of the README and the pages runs (issue 21, items 16-17). The examples'
convention is in ``tests/docs/examples.py``."""

from __future__ import annotations

import importlib
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import typer

from quadnav.cli.main import app
from tests.cli.test_help_examples import COMMANDS as CHECKED
from tests.docs.examples import (
    DOCS,
    INSTALL,
    ROOT,
    Block,
    all_blocks,
    blocks,
    quadnav_argv,
    shell_line,
)
from tests.script_module import load_script
from tests.shared_data import SHARED

TIMEOUT_S = 300
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _reference() -> Any:
    """docs/gen/reference.py, the generated pages' maker."""
    return load_script(DOCS / "gen" / "reference.py", "docs_reference")


def _quiet_env() -> dict[str, str]:
    env = dict(os.environ)
    env.update(NO_MKDOCS_2_WARNING="1", DISABLE_MKDOCS_2_WARNING="true", COLUMNS="100")
    src = str(ROOT / "src")
    env["PYTHONPATH"] = os.pathsep.join(p for p in (src, env.get("PYTHONPATH")) if p)
    return env


# ----------------------------------------------------------------------------- the site


@pytest.mark.skipif(
    importlib.util.find_spec("mkdocs") is None, reason="mkdocs is not installed ('.[test]')"
)
def test_the_site_builds_strict(tmp_path: Path) -> None:
    site = tmp_path / "site"
    cmd = [sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(site)]
    proc = subprocess.run(
        cmd, cwd=ROOT, env=_quiet_env(), capture_output=True, text=True, timeout=TIMEOUT_S
    )
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{proc.stderr[-4000:]}"
    reference = _reference()
    for page in reference.PAGES:
        built = site / page.removesuffix(".md") / "index.html"
        assert built.is_file(), f"{page} was not generated"
    for nav in ("SUMMARY", "reference/SUMMARY"):
        assert not (site / nav).exists(), f"the navigation file {nav}.md is published as a page"
    text = (site / "reference" / "configuration" / "index.html").read_text(encoding="utf-8")
    assert "gps.delay_s" in text and "vision.min_sigma_m" in text


def _nav_links(summary: Path, generated: dict[str, str]) -> list[str]:
    """Every page the navigation links to, relative to docs/ (a folder link reads that
    folder's SUMMARY.md, generated or not)."""
    text = generated.get(summary.relative_to(DOCS).as_posix())
    if text is None:
        text = summary.read_text(encoding="utf-8")
    base = summary.parent
    pages = []
    for target in LINK.findall(text):
        if target.endswith("/"):
            pages += _nav_links(base / target / "SUMMARY.md", generated)
        else:
            pages.append((base / target).resolve().relative_to(DOCS.resolve()).as_posix())
    return pages


def test_the_navigation_lists_every_page_and_every_listed_page_exists() -> None:
    reference = _reference()
    generated = {
        "reference/SUMMARY.md": reference.reference_nav(),
        **dict.fromkeys(reference.PAGES, ""),
    }
    listed = _nav_links(DOCS / "SUMMARY.md", generated)
    assert len(listed) == len(set(listed)), "a page is listed twice in the navigation"
    missing = [p for p in listed if p not in generated and not (DOCS / p).is_file()]
    assert not missing, f"docs/SUMMARY.md lists pages that do not exist: {missing}"
    on_disk = {
        p.relative_to(DOCS).as_posix()
        for p in DOCS.rglob("*.md")
        if p.relative_to(DOCS).parts[0] != "gen" and p.name != "SUMMARY.md"
    }
    unlisted = sorted(on_disk - set(listed))
    assert not unlisted, f"pages not in the navigation (docs/SUMMARY.md): {unlisted}"
    assert not on_disk & set(reference.PAGES), "a generated page is also written by hand"


# ----------------------------------------------------------------------------- examples


def _command(argv: list[str]) -> tuple[tuple[str, ...], Any]:
    """The longest command path ``argv`` starts with, and its click command."""
    cmd: Any = typer.main.get_command(app)
    path: list[str] = []
    while argv[len(path) :] and argv[len(path)] in getattr(cmd, "commands", {}):
        cmd = cmd.commands[argv[len(path)]]
        path.append(argv[len(path)])
    return tuple(path), cmd


def _validate(argv: list[str]) -> None:
    """Parse a line as the command would and validate it as the --help examples are."""
    path, cmd = _command(argv)
    assert path, f"quadnav {argv[:1]}: no such command"
    ctx = cmd.make_context(" ".join(path), argv[len(path) :])  # a bad option raises here
    if path in CHECKED:
        importlib.import_module(CHECKED[path]).check_example(ctx.params)


def _workdir(tmp_path: Path) -> Path:
    """A fresh folder whose ``../shared`` is the shared data's parent."""
    work = tmp_path / "work"
    work.mkdir()
    (tmp_path / "shared").symlink_to(SHARED.parent, target_is_directory=True)
    return work


def _run(block: Block, line_no: int, text: str, expect: int, work: Path) -> None:
    env = _quiet_env() | {"PY": sys.executable}
    script = 'quadnav() { "$PY" -m quadnav "$@"; }\n' + shell_line(text)
    where = f"{block.page}:{line_no}: {text}"
    try:
        proc = subprocess.run(
            ["bash", "-c", script],
            cwd=work,
            env=env,
            capture_output=True,
            text=True,
            timeout=TIMEOUT_S,
            stdin=subprocess.DEVNULL,
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"{where}\ntook more than {TIMEOUT_S} s")
    assert proc.returncode == expect, (
        f"{where}\nexited {proc.returncode}, expected {expect}\n"
        f"stderr: {proc.stderr[-2000:]}\nstdout: {proc.stdout[-1000:]}"
    )


def _install_line(block: Block, line_no: int, text: str, work: Path) -> None:
    """The README's install lines: the quadnav part runs; the pytest line is CI's."""
    m = INSTALL.match(text)
    assert m, f"{block.page}:{line_no}: not the install line the docs test knows: {text}"
    rest = m.group(1)
    if rest.startswith(".venv/bin/quadnav "):
        _run(block, line_no, rest, 0, work)
        return
    assert rest.startswith(".venv/bin/pytest"), f"{block.page}:{line_no}: {text}"
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    assert text in ci, f"{block.page}:{line_no}: .ci/run does not run {text!r}"


BLOCKS = all_blocks()
PARAMS = [pytest.param(b, id=b.id, marks=[pytest.mark.slow] if b.slow else []) for b in BLOCKS]


@pytest.mark.parametrize("block", [b for b in BLOCKS if b.slow], ids=lambda b: b.id)
def test_the_slow_examples_parse_and_validate(
    block: Block, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A ``# slow:`` block runs with the long tests; here its lines are checked as a block
    not run."""
    monkeypatch.chdir(_workdir(tmp_path))
    for line in block.lines:
        argv = quadnav_argv(line.text)
        assert argv is not None, f"{block.page}:{line.number}: {line.text!r} is not quadnav"
        if line.expect == 0:  # (a line meant to fail is left to the slow run)
            _validate(argv)


@pytest.mark.parametrize("block", PARAMS)
def test_every_shell_example_runs(
    block: Block, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    names_shared = any("../shared/data" in line.text for line in block.lines)
    if names_shared and not SHARED.is_dir():
        pytest.skip(f"shared test data not found at {SHARED}")
    work = _workdir(tmp_path)
    for line in block.lines:
        argv = quadnav_argv(line.text)
        if block.not_run:
            if argv is not None:
                monkeypatch.chdir(work)  # the examples name ../shared/data from there
                _validate(argv)
        elif block.first_of_readme:
            _install_line(block, line.number, line.text, work)
        else:
            assert argv is not None, (
                f"{block.page}:{line.number}: {line.text!r} is not a quadnav command; a block "
                "with other commands starts with '# not run: <reason>'"
            )
            _run(block, line.number, line.text, line.expect, work)
    if block.not_run:
        pytest.skip(f"{block.page}:{block.number} not run ({block.not_run}); parsed and validated")


def test_the_example_reader_follows_the_convention(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(
        "text\n```bash\nquadnav run \\\n    --seeds 2   # two seeds\n# a comment\n"
        "quadnav eval a b   # exits 2: no files\n```\n\n```python\nquadnav no\n```\n"
        "```bash\n# not run: needs a serial port\nquadnav link serial /dev/ttyUSB0\nls -l\n```\n"
        "```bash\n# slow: a minute of flights\nquadnav run outdoor_gps\n```\n",
        encoding="utf-8",
    )
    first, second, third = blocks(page, root=tmp_path)
    assert (first.slow, second.slow, third.slow) == ("", "", "a minute of flights")
    assert third.not_run == "" and [x.text for x in third.lines] == ["quadnav run outdoor_gps"]
    assert [(x.number, x.text, x.expect) for x in first.lines] == [
        (3, "quadnav run --seeds 2", 0),
        (6, "quadnav eval a b", 2),
    ]
    assert first.not_run == "" and second.not_run == "needs a serial port"
    assert [x.text for x in second.lines] == ["quadnav link serial /dev/ttyUSB0", "ls -l"]


def test_a_failing_example_is_reported_with_its_page_and_line(tmp_path: Path) -> None:
    block = Block("docs/x.md", 3, (), "", False)
    with pytest.raises(AssertionError, match=r"docs/x\.md:4: quadnav eval nothing\.txt"):
        _run(block, 4, "quadnav eval nothing.txt", 0, tmp_path)
