"""The shell examples of the README and the documentation pages, as the docs test runs them.

The convention (docs/development.md should say it to page writers):

- Fenced ```` ```bash ```` (or ``sh``/``shell``) blocks are examples; other fences are not.
- A logical line joins backslash continuations; a comment after ``  #`` is stripped, and
  lines that are only a comment are skipped.
- Every line of a block starts with ``quadnav `` (or ``.venv/bin/quadnav ``) and is run, in
  order, in one fresh folder per block (so a line may read what an earlier one wrote), with
  ``../shared`` pointing at the shared data: examples may name ``../shared/data/...``. A block
  naming ``../shared/data`` is skipped (with the reason) when the shared data is absent.
- A line exits 0, unless its comment says ``# exits N`` (the whole comment, or its start:
  ``# exits 2: no such file``): then it must exit N.
- A block whose first line is ``# not run: <reason>`` is not run (hardware, hours of work):
  its ``quadnav`` lines are only parsed and validated as the ``--help`` examples are (options,
  ``--set`` keys and values), and its other lines are not checked.
- A block whose first line is ``# slow: <reason>`` (a minute or more of flights or renders)
  runs with the long tests (``pytest -m slow``); CI parses and validates its ``quadnav`` lines
  as those of a block not run.
- The README's first block is the install: ``python3 -m venv .venv && .venv/bin/pip install
  ... && .venv/bin/quadnav ...`` runs its ``quadnav`` part, and ``... && .venv/bin/pytest``
  must be exactly the line ``.ci/run`` runs.
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})\s*([\w+-]*)")
SHELL = {"bash", "sh", "shell"}
EXITS = re.compile(r"^#\s*exits\s+(\d+)\b")
NOT_RUN = re.compile(r"^#\s*not run:\s*(\S.*)$")
SLOW = re.compile(r"^#\s*slow:\s*(\S.*)$")
PREFIXES = ("quadnav ", ".venv/bin/quadnav ")
INSTALL = re.compile(r"^python3 -m venv \.venv && \.venv/bin/pip install .+? && (\S.*)$")


@dataclass(frozen=True, slots=True)
class Line:
    """One logical line of an example: where it starts, the command, the exit code expected."""

    number: int
    text: str
    expect: int = 0


@dataclass(frozen=True, slots=True)
class Block:
    """A fenced shell block of a page."""

    page: str  # relative to the project
    number: int  # the line of its opening fence
    lines: tuple[Line, ...]
    not_run: str  # the reason, or "" for a block that runs
    first_of_readme: bool
    slow: str = ""  # the reason it runs with the long tests only, or ""

    @property
    def id(self) -> str:
        first = self.lines[0].text.split()[:3] if self.lines else []
        return f"{self.page}:{self.number} {' '.join(first)}"


def doc_pages() -> list[Path]:
    """The README and every Markdown page under docs/ (not the generators' folder)."""
    pages = sorted(p for p in DOCS.rglob("*.md") if "gen" not in p.relative_to(DOCS).parts[:1])
    return [ROOT / "README.md", *pages]


def _strip_comment(text: str) -> tuple[str, str]:
    """The command and its trailing comment (after whitespace and ``#``)."""
    m = re.search(r"\s+#", text)
    if m is None:
        return text.strip(), ""
    return text[: m.start()].strip(), text[m.start() :].strip()


def logical_lines(raw: list[tuple[int, str]]) -> Iterator[tuple[int, str, str]]:
    """(first line number, command, comment) with continuations joined; a line that is only a
    comment comes with an empty command."""
    pending: list[str] = []
    start = 0
    for number, text in raw:
        if not pending:
            start = number
        if text.rstrip().endswith("\\"):
            pending.append(text.rstrip()[:-1])
            continue
        joined = " ".join(part.strip() for part in [*pending, text])
        pending = []
        if not joined:
            continue
        if joined.startswith("#"):
            yield start, "", joined
            continue
        command, comment = _strip_comment(joined)
        yield start, command, comment
    if pending:
        yield start, " ".join(p.strip() for p in pending), ""


def _fenced(path: Path) -> Iterator[tuple[int, list[tuple[int, str]]]]:
    """(opening line number, [(line number, text)]) of each shell block of a page."""
    lines = path.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if m is None:
            i += 1
            continue
        fence, lang, start = m.group(2), m.group(3).lower(), i
        body: list[tuple[int, str]] = []
        i += 1
        while i < len(lines) and not lines[i].strip().startswith(fence):
            body.append((i + 1, lines[i]))
            i += 1
        i += 1
        if lang in SHELL:
            yield start + 1, body


def blocks(path: Path, root: Path = ROOT) -> list[Block]:
    page = path.relative_to(root).as_posix()
    out = []
    for k, (number, body) in enumerate(_fenced(path)):
        parsed = list(logical_lines(body))
        reason = slow = ""
        if parsed and not parsed[0][1]:
            m = NOT_RUN.match(parsed[0][2])
            reason = m.group(1) if m else ""
            m = SLOW.match(parsed[0][2])
            slow = m.group(1) if m else ""
        lines = []
        for n, command, comment in parsed:
            if not command:
                continue
            m = EXITS.match(comment)
            lines.append(Line(n, command, int(m.group(1)) if m else 0))
        first = page == "README.md" and k == 0
        out.append(Block(page, number, tuple(lines), reason, first, slow))
    return out


def all_blocks() -> list[Block]:
    return [b for page in doc_pages() for b in blocks(page)]


def quadnav_argv(text: str) -> list[str] | None:
    """The arguments after ``quadnav`` of a quadnav line; ``None`` for another line."""
    for prefix in PREFIXES:
        if text.startswith(prefix):
            return shlex.split(text[len(prefix) :])
    return None


def shell_line(text: str) -> str:
    """A quadnav line as bash runs it (``quadnav`` is a function that calls ``$PY -m quadnav``,
    so globs and quoting behave as in the user's shell)."""
    for prefix in PREFIXES:
        if text.startswith(prefix):
            return "quadnav " + text[len(prefix) :]
    raise ValueError(text)
