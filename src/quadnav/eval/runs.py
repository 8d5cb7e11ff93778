"""One table over many run folders of any kind (``quadnav eval --table runs/*``).

Each folder's ``metrics.json`` gives its rows: its own summary ``table`` (planar, eval, run/nav,
sim), one row per comparison (replay: ``quadnav_vs_px4``, ...), or its flat named numbers
(markers, and any kind without a table). A folder without a readable ``metrics.json`` is listed
with the reason instead of stopping the table.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from quadnav.eval.na import is_na
from quadnav.io.run_folder import read_run_status

__all__ = ["Cell", "RunRow", "compare_runs", "format_table", "run_rows"]

Cell = float | int | str | None
_SKIP = {"kind", "table", "run_dir"}


@dataclass(frozen=True, slots=True, kw_only=True)
class RunRow:
    """One row of the table: the run folder, its kind, and its named values (or a note)."""

    run: str
    kind: str
    cells: dict[str, Cell] = field(default_factory=dict)
    note: str = ""


def _flat(data: dict[str, object]) -> dict[str, Cell]:
    """The values of ``data`` that fit a cell: numbers, flags and short text."""
    out: dict[str, Cell] = {}
    for k, v in data.items():
        if k in _SKIP:
            continue
        if isinstance(v, bool):
            out[k] = str(v).lower()
        elif isinstance(v, str) and is_na(v):
            out[k] = v  # a metric that says why it is missing, however long the reason
        elif (
            isinstance(v, int | float)
            or v is None
            or (isinstance(v, str) and len(v) <= 60 and "\n" not in v)
        ):
            out[k] = v
    return out


def run_rows(folder: Path) -> list[RunRow]:
    """The rows of one run folder (at least one, with a note when it has no metrics)."""
    name = Path(folder).name
    f = Path(folder) / "metrics.json"
    if not Path(folder).is_dir():
        return [RunRow(run=name, kind="", note="not a folder")]
    status = read_run_status(Path(folder))
    if status not in (None, "complete"):  # interrupted, failed, or still running (or killed)
        return [RunRow(run=name, kind="", note=f"marked {status}: its results are incomplete")]
    if not f.is_file():
        return [RunRow(run=name, kind="", note="no metrics.json")]
    try:
        data = json.loads(f.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError, OSError) as exc:
        return [RunRow(run=name, kind="", note=f"metrics.json unreadable: {exc}")]
    if not isinstance(data, dict):
        return [RunRow(run=name, kind="", note="metrics.json is not a JSON object")]
    pairs = {k: v for k, v in data.items() if "_vs_" in k and isinstance(v, dict)}
    kind = str(data.get("kind") or ("replay" if pairs else "unknown"))
    table = data.get("table")
    if isinstance(table, list) and table and all(isinstance(r, dict) for r in table):
        return [RunRow(run=name, kind=kind, cells=_flat(r)) for r in table]
    if pairs:
        return [
            RunRow(run=name, kind=kind, cells={"pair": k.replace("_vs_", " vs "), **_flat(v)})
            for k, v in pairs.items()
        ]
    cells = _flat(data)
    if not cells:
        return [RunRow(run=name, kind=kind, note="metrics.json holds no named numbers")]
    return [RunRow(run=name, kind=kind, cells=cells)]


def compare_runs(run_dirs: list[Path]) -> list[RunRow]:
    """The rows of several run folders, in the order given."""
    return [row for d in run_dirs for row in run_rows(d)]


def _cell(v: Cell) -> str:
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.6g}"
    return "" if v is None else str(v)


def _columns(rows: list[RunRow]) -> list[str]:
    return list(dict.fromkeys(k for row in rows for k in row.cells))


def format_table(rows: list[RunRow], fmt: Literal["markdown", "csv"] = "markdown") -> str:
    """CSV: one table, ``run, kind, note`` then every column in order of first appearance.
    Markdown: a table per kind with that kind's own columns, then the folders without metrics."""
    if fmt == "csv":
        cols = _columns(rows)
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["run", "kind", "note", *cols])
        for row in rows:
            w.writerow([row.run, row.kind, row.note, *(_cell(row.cells.get(c)) for c in cols)])
        return buf.getvalue()
    blocks = []
    for kind in dict.fromkeys(r.kind for r in rows if not r.note):
        group = [r for r in rows if r.kind == kind and not r.note]
        cols = _columns(group)
        body = [[r.run, *(_cell(r.cells.get(c)) for c in cols)] for r in group]
        blocks.append(f"{kind}:\n\n" + _markdown(["run", *cols], body))
    noted = [[r.run, r.kind, r.note] for r in rows if r.note]
    if noted:
        blocks.append("without metrics:\n\n" + _markdown(["run", "kind", "note"], noted))
    return "\n".join(blocks)


def _markdown(headers: list[str], body: list[list[str]]) -> str:
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in body]
    return "\n".join(lines) + "\n"
