"""Thesis 002's flights on a position sent as ``X<cm>Y<cm>Z<cm>F`` frames over a pseudo-terminal:
the link's share (the true position at 10 Hz, whole centimetres, Euler velocity) under line
noise, a companion that stops sending (a SLAM loss), the run folder, and a short flight on the
stereo SLAM's position from rendered images."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from quadnav.errors import ConfigError
from quadnav.experiments.flight import BUILTIN, FlightConfig, builtin_config, run_flight
from quadnav.experiments.flight_study import flight_metrics, write_flight_run
from quadnav.experiments.slam_flight import SerialLinkSection, SerialPositionLoop
from quadnav.geometry.rotations import Pose
from quadnav.io.config import load_config
from quadnav.messages import StateEstimate


def flight(name: str, *overrides: str) -> FlightConfig:
    return load_config(FlightConfig, None, list(overrides), base=builtin_config(name))


def test_the_six_flights_are_built_in_with_both_laws_and_the_thesis_gains() -> None:
    names = [n for n in BUILTIN if n.startswith("thesis002_slam_")]
    assert len(names) == 6
    for n in names:
        c = flight(n)
        assert c.position_source == "slam" and c.link.rig == "zed"
        assert c.link.frame_rate_hz == 10.0
        assert c.controller == ("pd" if n.endswith("_pd") else "nested_saturation")
        if c.controller == "pd":
            assert c.el_pd_gains == "table_5_1"
    sq = flight("thesis002_slam_square_pd").trajectory.points_m
    assert np.ptp(np.array(sq)[:, 0]) == pytest.approx(1.2)
    assert np.ptp(np.array(sq)[:, 1]) == pytest.approx(1.2)


def test_only_the_euler_lagrange_vehicle_flies_on_the_serial_frames() -> None:
    with pytest.raises(ConfigError, match="position_source"):
        flight("circle", "position_source=slam")


@pytest.mark.parametrize("name", ["thesis002_slam_sigmoid_pd", "thesis002_slam_sigmoid_nested"])
def test_the_link_under_line_noise_costs_centimetres_and_loses_no_frame(
    name: str, tmp_path: Path
) -> None:
    """The true position through the link with 20 random bytes of noise per frame on average:
    every frame arrives (noise sits between frames), the noise is counted, the flight tracks
    within 10 cm. The nested saturations, which track the sigmoid to a tenth of a millimetre on
    the true state, lose centimetres to the link (10 Hz, rounding, the Euler velocity); the
    PD's own lag (7 cm) is of the same order as the link's effect, either way."""
    truth = run_flight(flight(name, "position_source=truth"))
    noisy = run_flight(flight(name, "position_source=serial_truth", "link.garbage_per_frame=20"))
    assert truth.link is None and noisy.link is not None
    c = noisy.link.counts
    assert (
        c["frames_sent"]
        == c["frames_received"]
        == pytest.approx(10 * truth.config.duration_s, abs=1)
    )
    assert c["garbage_bytes"] > 5 * c["frames_sent"]
    assert c["position_held_s"] == 0.0
    e_truth = flight_metrics(truth).tracking
    e_link = flight_metrics(noisy).tracking
    assert e_truth is not None and e_link is not None
    assert max(float(e_truth.tracking_rmse_m), float(e_link.tracking_rmse_m)) < 0.10
    if name.endswith("nested"):
        assert float(e_truth.tracking_rmse_m) < 0.001 < 0.005 < float(e_link.tracking_rmse_m)
    run_dir, _ = write_flight_run(noisy, runs_root=tmp_path)
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["link"]["garbage_bytes"] == c["garbage_bytes"]
    assert (run_dir / "link.csv").exists() and (run_dir / "plots" / "link.png").exists()


def _estimate(t_ns: int, p: np.ndarray) -> StateEstimate:
    return StateEstimate(t_ns=t_ns, p_W_B=p, v_W_B=np.zeros(3), q_W_B_xyzw=np.array([0, 0, 0, 1.0]),
                         x=np.concatenate([p, np.zeros(9)]), names=tuple("abcdefghijkl"),
                         w_B=np.zeros(3))  # fmt: skip


def test_a_companion_that_stops_sending_leaves_the_last_position_held_and_no_velocity() -> None:
    """A SLAM that tracks a 0.5 m/s walk for 1 s and is lost after: the flight controller keeps
    the last position it was sent, its velocity goes to zero once ``lost_after_s`` (0.3 s) has
    passed without a frame, and the time held is counted."""
    loop = SerialPositionLoop(SerialLinkSection(lost_after_s=0.3), "serial_truth",
                              start=Pose.identity(), path_W=np.zeros((1, 3)), seed=0)  # fmt: skip

    def sample(truth: object, t_ns: int, rng: object) -> object | None:
        return SimpleNamespace(p_W_B=np.array([0.5 * t_ns * 1e-9, 0, 1])) if t_ns <= 1e9 else None

    loop.sensor = SimpleNamespace(  # type: ignore[assignment]
        sample=sample,
        record=lambda: SimpleNamespace(frames=30, states=10, stage_ms={}, events=[(10**9, "lost")]),
    )
    out = []
    for k in range(0, 3001):  # 3 s in 1 ms steps
        t = k * 1_000_000
        p = np.array([0.5 * t * 1e-9, 0.0, 1.0])
        truth = SimpleNamespace(t_ns=t, p_W_B=p)  # (what the stub camera is handed)
        out.append(loop.estimate(_estimate(t, p), truth))  # type: ignore[arg-type]
    rec = loop.close()
    at_1_2s, at_2s = out[1200], out[2000]
    assert at_1_2s.p_W_B[0] == pytest.approx(0.5, abs=0.006)
    assert at_1_2s.v_W_B[0] == pytest.approx(0.5, abs=0.1)  # still the last Euler velocity
    assert at_2s.p_W_B[0] == at_1_2s.p_W_B[0] and not at_2s.v_W_B.any()
    # the last frame left within a tenth of a period before 1 s (the sender's tolerance)
    assert rec.counts["position_held_s"] == pytest.approx(3.0 - 1.0 - 0.3, abs=0.011)
    assert rec.counts["frames_sent"] == 11 and rec.events == ((1.0, "lost"),)


@pytest.mark.slow
def test_a_hover_on_the_slam_position_flies_as_on_the_truth_within_centimetres() -> None:
    """Four seconds of the hover (switched on 0.4 m low) on the stereo SLAM from the ZED
    rendered in a room: every pair tracked and sent, the SLAM's position within 3 cm of the
    truth, the path within 5 cm of the same flight on the true position over the same link."""
    run = run_flight(flight("thesis002_slam_hover_pd", "duration_s=4"))
    truth = run_flight(
        flight("thesis002_slam_hover_pd", "duration_s=4", "position_source=serial_truth")
    )
    assert run.link is not None
    c, m = run.link.counts, run.link.metrics()
    # (pairs at 0, 0.1, ..., 4 s: the first at the start, the SLAM's origin)
    assert c["slam_frames"] == c["slam_states"] == c["frames_received"] == 41
    assert float(m["sent_position_rmse_m"]) < 0.03  # type: ignore[arg-type]
    assert np.linalg.norm(run.p - truth.p, axis=1).max() < 0.05
    assert np.linalg.norm(truth.p[-1] - truth.p[0]) > 0.3  # (it did fly somewhere)
