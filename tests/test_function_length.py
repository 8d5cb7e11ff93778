"""No function in ``src/`` is longer than 80 lines (issue 13, item 7).

A function's length runs from its ``def`` line to its last line, docstring and nested functions
included (a nested function counts on its own too).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "quadnav"
MAX_LINES = 80

#: Functions allowed over the limit (none: issue 13 split the last ones).
ALLOWED: frozenset[str] = frozenset()


def long_functions(source: str, rel: str) -> dict[str, int]:
    """``path:qualified.name`` -> length of every function over ``MAX_LINES`` in ``source``."""
    found: dict[str, int] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                name = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    n = (child.end_lineno or child.lineno) - child.lineno + 1
                    if n > MAX_LINES:
                        found[f"{rel}:{name}"] = n
                visit(child, f"{name}.")
            else:
                visit(child, prefix)

    visit(ast.parse(source), "")
    return found


def _src_long_functions() -> dict[str, int]:
    found: dict[str, int] = {}
    for path in sorted(SRC.rglob("*.py")):
        found |= long_functions(path.read_text(encoding="utf-8"), path.relative_to(SRC).as_posix())
    return found


def test_no_function_in_src_is_over_80_lines() -> None:
    over = {k: n for k, n in _src_long_functions().items() if k not in ALLOWED}
    assert not over, f"functions over {MAX_LINES} lines: " + ", ".join(
        f"{k} ({n})" for k, n in sorted(over.items())
    )


def test_the_allow_list_holds_only_functions_still_too_long() -> None:
    """Once one is split, it leaves the list (so the list can only shrink)."""
    stale = ALLOWED - set(_src_long_functions())
    assert not stale, f"split already, remove from ALLOWED: {sorted(stale)}"


@pytest.mark.parametrize(
    ("body_lines", "flagged"),
    [(MAX_LINES - 1, False), (MAX_LINES, True)],  # + the def line
)
def test_the_count_includes_the_def_line_and_sees_methods(body_lines: int, flagged: bool) -> None:
    body = "\n".join(f"        x{i} = {i}" for i in range(body_lines))
    source = f"class A:\n    def method(self) -> None:\n{body}\n"
    assert bool(long_functions(source, "m.py")) is flagged
    if flagged:
        assert long_functions(source, "m.py") == {"m.py:A.method": MAX_LINES + 1}
