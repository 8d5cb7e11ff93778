"""Where the real test data lives (../shared/data, see its README) and a skip marker for when
it is absent."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def needs(path: Path) -> pytest.MarkDecorator:
    return pytest.mark.skipif(not path.exists(), reason=f"shared test data not found at {path}")


PX4_SITL = SHARED / "px4" / "sample_logging_tagged_and_default_params.ulg"
PX4_EVENTS = SHARED / "px4" / "sample_px4_events.ulg"
