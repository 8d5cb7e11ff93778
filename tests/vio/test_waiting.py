"""An estimator that cannot start says so, and why (issue 22: a monocular VIO that fails in
flight on a steady cruise cannot see its scale again, and did so in silence): while the
visual-inertial start refuses window after window, a ``waiting`` event every few seconds names
how long and the last refusal; none once started. A rendered room flight with no still start,
the start made to refuse by a stand-in for the initialisation."""

from __future__ import annotations

import re

import pytest

from quadnav.io.datasets import VisualInertialDataset
from quadnav.messages import ImuSample
from quadnav.vio import VioEstimator
from quadnav.vio.estimator import WAITING_REPORT_S
from quadnav.vio.initialization import InitFailure
from tests.vio.rendered import rendered


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> VisualInertialDataset:
    spec = {"duration_s": 8.0, "still_s": 0.0, "rig": "euroc_mono", "seed": 3}
    return rendered(tmp_path_factory, "room_easy", **spec)


def _events(ds: VisualInertialDataset, refuse: bool) -> list[tuple[float, str, str]]:
    vio = VioEstimator(ds.rig)
    if refuse:
        vio._visual_init = lambda window: InitFailure(  # type: ignore[method-assign]
            stage="alignment", reason="the scale is not observable in this window (test)"
        )
    t0 = ds.frames_of("cam0")[0].t_ns
    for item in ds.stream():
        if isinstance(item, ImuSample) or item.camera == "cam0":
            vio.push(item)  # type: ignore[arg-type]
    return [((e.t_ns - t0) / 1e9, e.kind, e.detail) for e in vio.events]


def test_a_start_refused_window_after_window_is_reported_with_its_reason(
    flight: VisualInertialDataset,
) -> None:
    events = _events(flight, refuse=True)
    assert not [e for e in events if e[1] in ("initialized", "reinitialized")]
    waiting = [e for e in events if e[1] == "waiting"]
    # 8 s of flight, a report every 5 s from the first refused window: one
    assert 1 <= len(waiting) <= int(8.0 / WAITING_REPORT_S), events
    for t, _, detail in waiting:
        assert "not started for" in detail and "(test)" in detail, detail
        since = float(re.search(r"for ([0-9.]+) s", detail).group(1))  # type: ignore[union-attr]
        assert WAITING_REPORT_S - 0.2 <= since <= t, (t, detail)
    # the real start: on this flight it starts, and says nothing of waiting before or after
    real = _events(flight, refuse=False)
    starts = [e for e in real if e[1] == "initialized"]
    assert starts and starts[0][0] < WAITING_REPORT_S, real
    assert not [e for e in real if e[1] == "waiting"], real
