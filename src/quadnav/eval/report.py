"""Self-contained HTML run reports: config, metrics tables and plots embedded in one file.

The page has no external resources (images are inlined as base64), so it opens offline.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from quadnav.errors import EvalError

__all__ = ["ReportSection", "ReportTable", "write_report"]

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; color: #222; }
h1 { font-size: 1.6em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: .2em; }
table.metrics { border-collapse: collapse; margin: 1em 0; font-size: .92em; }
table.metrics th, table.metrics td { border: 1px solid #bbb; padding: .3em .6em; text-align: right; }
table.metrics th { background: #f0f0f0; } table.metrics td:first-child { text-align: left; }
img { max-width: 100%; border: 1px solid #ddd; margin: .5em 0; }
pre { background: #f7f7f7; padding: 1em; overflow-x: auto; font-size: .85em; }
.caption { color: #555; font-size: .9em; }
"""


@dataclass(frozen=True, slots=True)
class ReportTable:
    caption: str
    headers: Sequence[str]
    rows: Sequence[Sequence[object]]


@dataclass(frozen=True, slots=True)
class ReportSection:
    heading: str
    text: str = ""
    tables: Sequence[ReportTable] = field(default_factory=tuple)
    images: Sequence[Path] = field(default_factory=tuple)
    code: str = ""


def _cell(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return html.escape(str(value))


def _table(t: ReportTable) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in t.headers)
    body = "".join(
        "<tr>" + "".join(f"<td>{_cell(v)}</td>" for v in row) + "</tr>" for row in t.rows
    )
    return (
        f'<p class="caption">{html.escape(t.caption)}</p>'
        f'<table class="metrics"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'
    )


def _image(path: Path) -> str:
    try:
        data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    except OSError as exc:
        raise EvalError(f"cannot embed {path} in the report: {exc.strerror}") from None
    alt = html.escape(Path(path).stem)
    return f'<figure><img alt="{alt}" src="data:image/png;base64,{data}"><figcaption class="caption">{alt}</figcaption></figure>'


def write_report(path: Path, *, title: str, sections: Sequence[ReportSection]) -> None:
    """Write ``report.html``: a title, then each section's text, tables, images and code."""
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        f'<p class="caption">quadnav report, written {_dt.datetime.now():%Y-%m-%d %H:%M:%S}</p>',
    ]
    for sec in sections:
        parts.append(f"<h2>{html.escape(sec.heading)}</h2>")
        if sec.text:
            parts.append(f"<p>{html.escape(sec.text)}</p>")
        parts.extend(_table(t) for t in sec.tables)
        parts.extend(_image(p) for p in sec.images)
        if sec.code:
            parts.append(f"<pre>{html.escape(sec.code)}</pre>")
    parts.append("</body></html>")
    try:
        Path(path).write_text("\n".join(parts), encoding="utf-8")
    except OSError as exc:
        raise EvalError(f"cannot write {path}: {exc.strerror}") from None
