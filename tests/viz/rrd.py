"""A recording read back with rerun's own reader (``rerun.chunk.RrdReader``), for the tests."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rerun.chunk import RrdReader


class StaticBatches:
    """An entity's static chunks (one per archetype logged, in whatever order and grouping the
    file holds them): :meth:`column` finds a component's column in whichever has it."""

    def __init__(self) -> None:
        self.batches: list[Any] = []

    def column(self, name: str) -> Any:
        for batch in self.batches:
            if name in batch.schema.names:
                return batch.column(name)
        raise KeyError(f"no static column {name!r}")


def rows_and_static(path: Path) -> tuple[dict[str, int], dict[str, StaticBatches]]:
    """Rows per entity over time, and the static chunks' record batches, by entity."""
    rows: dict[str, int] = {}
    static: dict[str, StaticBatches] = {}
    for chunk in RrdReader(path).stream():
        if chunk.is_static:
            static.setdefault(chunk.entity_path, StaticBatches()).batches.append(
                chunk.to_record_batch()
            )
        else:
            rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    return rows, static
