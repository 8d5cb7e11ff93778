from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import pytest

from quadnav.eval import ReportSection, ReportTable, write_report

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]  # fmt: skip


def make_report(tmp_path: Path) -> Path:
    img = tmp_path / "plot.png"
    fig, ax = plt.subplots(figsize=(4, 3))
    ax.plot([0, 1], [0, 1])
    fig.savefig(img, dpi=50)
    plt.close(fig)
    path = tmp_path / "report.html"
    write_report(
        path,
        title="A <test> report",
        sections=[
            ReportSection(
                heading="Metrics",
                tables=[ReportTable("stats", ["estimate", "rmse"], [["a&b", 1.25], ["c", 0.5]])],
            ),
            ReportSection(heading="Plots", images=[img]),
            ReportSection(heading="Config", code="x: <1>"),
        ],
    )
    img.unlink()  # the report must not depend on the file any more
    return path


def test_report_is_self_contained_and_escaped(tmp_path: Path) -> None:
    html = make_report(tmp_path).read_text()
    assert "A &lt;test&gt; report" in html and "a&amp;b" in html and "x: &lt;1&gt;" in html
    assert "data:image/png;base64," in html
    assert not re.search(r'(src|href)="(http|file|/)', html), "no external resources"


@pytest.mark.skipif(
    CHROMIUM is None, reason="Debian's chromium is not installed (.ci/run installs it)"
)
def test_report_renders_in_headless_chromium(tmp_path: Path) -> None:
    """Load the page offline; after load, record what the browser made of its table and images."""
    report = make_report(tmp_path)
    probe = tmp_path / "probe.html"
    probe.write_text(
        report.read_text().replace(
            "</body>",
            "<script>window.addEventListener('load', () => {"
            "document.body.setAttribute('data-images', [...document.images].map(i => i.naturalWidth).join(','));"
            "document.body.setAttribute('data-cells', [...document.querySelectorAll('table.metrics td')]"
            ".map(c => c.textContent).join('|'));});</script></body>",
        )
    )
    assert CHROMIUM is not None
    out = subprocess.run(
        [CHROMIUM, *FLAGS, f"--user-data-dir={tmp_path / 'profile'}", "--virtual-time-budget=5000",
         "--dump-dom", probe.as_uri()],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    body = re.search(r"<body[^>]*>", out.stdout)
    assert body is not None, out.stderr[-2000:]
    images = re.search(r'data-images="([^"]*)"', body.group(0))
    cells = re.search(r'data-cells="([^"]*)"', body.group(0))
    assert images is not None and cells is not None
    assert images.group(1) == "200", "the embedded PNG decodes to its 200 px width"
    assert cells.group(1) == "a&amp;b|1.25|c|0.5"
