"""A recording read back with rerun's own reader (``rerun.chunk.RrdReader``), for the tests."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rerun.chunk import RrdReader


def rows_and_static(path: Path) -> tuple[dict[str, int], dict[str, Any]]:
    """Rows per entity over time, and the static chunks' record batches, by entity."""
    rows: dict[str, int] = {}
    static: dict[str, Any] = {}
    for chunk in RrdReader(path).stream():
        if chunk.is_static:
            static[chunk.entity_path] = chunk.to_record_batch()
        else:
            rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    return rows, static
