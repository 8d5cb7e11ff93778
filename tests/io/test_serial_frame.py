"""Thesis 002's serial frame: encoder, streaming decoder under garbage, velocities, and the
`quadnav link serial` command over a pseudo-terminal pair."""

from __future__ import annotations

import os
import re
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.errors import IoError
from quadnav.io.serial_frame import FrameDecoder, VelocityEstimator, encode

FRAME = re.compile(rb"X-?\d{1,6}Y-?\d{1,6}Z-?\d{1,6}F")
cm = st.integers(min_value=-999_999, max_value=999_999)


def test_encode_matches_the_thesis_layout() -> None:
    assert encode(1.234, -0.5, 2.0) == b"X123Y-50Z200F"
    with pytest.raises(IoError):
        encode(float("nan"), 0.0, 0.0)
    with pytest.raises(IoError):
        encode(1e5, 0.0, 0.0)


@given(st.lists(st.tuples(cm, cm, cm), min_size=1, max_size=20), st.integers(1, 7))
def test_round_trip_in_any_chunking(frames: list[tuple[int, int, int]], chunk: int) -> None:
    data = b"".join(f"X{x}Y{y}Z{z}F".encode() for x, y, z in frames)
    dec = FrameDecoder()
    out = []
    for i in range(0, len(data), chunk):
        out += dec.feed(data[i : i + chunk])
    assert [(f.x_cm, f.y_cm, f.z_cm) for f in out] == frames
    assert dec.dropped == 0 and dec.garbage_bytes == 0


@settings(max_examples=300)
@given(
    st.lists(st.tuples(st.binary(max_size=40), st.tuples(cm, cm, cm)), min_size=1, max_size=15),
    st.binary(max_size=40),
    st.integers(1, 9),
)
def test_garbage_between_frames_never_corrupts_them(pieces, tail: bytes, chunk: int) -> None:
    """Garbage interleaved with valid frames: every frame sent comes out, nothing else does
    (garbage that itself spells a complete frame is indistinguishable without a checksum)."""
    stream = b""
    sent = []
    for garbage, (x, y, z) in pieces:
        assume(not FRAME.search(garbage))
        stream += garbage + f"X{x}Y{y}Z{z}F".encode()
        sent.append((x, y, z))
    assume(not FRAME.search(tail))
    stream += tail
    dec = FrameDecoder()
    out = []
    for i in range(0, len(stream), chunk):
        out += dec.feed(stream[i : i + chunk])
    assert [(f.x_cm, f.y_cm, f.z_cm) for f in out] == sent


@given(st.binary(max_size=500))
def test_any_bytes_never_raise_and_only_well_formed_frames_come_out(data: bytes) -> None:
    out = FrameDecoder().feed(data)
    found = [tuple(int(v) for v in re.findall(rb"-?\d+", m.group())) for m in FRAME.finditer(data)]
    assert [(f.x_cm, f.y_cm, f.z_cm) for f in out] == found


def test_bad_frames_are_dropped_and_counted() -> None:
    dec = FrameDecoder()
    bad = [
        b"X12Y34F",
        b"X1234567Y1Z1F",
        b"X12Y-Z3F",
        b"X1Y2Z",
        b"X1Y2\x00Z3F",
        b"X--1Y2Z3F",
        b"X1Y2Z3ZF",
    ]
    out = dec.feed(b"".join(bad) + b"X1Y2Z3F")
    assert [(f.x_cm, f.y_cm, f.z_cm) for f in out] == [(1, 2, 3)]
    assert dec.dropped == len(bad)


def test_velocities_euler_and_filtered() -> None:
    est = VelocityEstimator(dt_s=0.1, tau_s=0.2)
    for k in range(60):  # 0.5 m/s along x, with 5 mm of position noise (the frame's resolution)
        est.update((0.05 * k + 0.005 * (-1) ** k, 0.0, 1.0))
    assert est.euler[0] in (pytest.approx(0.4), pytest.approx(0.6))  # the noise, undamped
    assert est.filtered[0] == pytest.approx(0.5, abs=0.05)  # the noise, damped
    assert est.euler[2] == 0.0


def test_link_serial_over_a_pseudo_terminal(tmp_path: Path) -> None:
    import tty

    master, slave = os.openpty()
    tty.setraw(master)
    traj = tmp_path / "t.tum"
    pts = np.array([[0.01 * k, -0.02 * k, 1.5] for k in range(50)])
    traj.write_text(
        "".join(f"{k * 0.1:.1f} {x} {y} {z} 0 0 0 1\n" for k, (x, y, z) in enumerate(pts))
    )
    received = bytearray()

    def reader() -> None:
        # read until all 50 frames are in (or 10 s pass), however the writes were split
        import select

        deadline = time.monotonic() + 10.0
        while received.count(b"F") < 50 and time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.1)
            if ready:
                try:
                    received.extend(os.read(master, 4096))
                except OSError:
                    break

    th = threading.Thread(target=reader, daemon=True)
    th.start()
    res = CliRunner().invoke(
        app, ["link", "serial", os.ttyname(slave), "--from", str(traj), "--rate", "0"]
    )
    th.join(timeout=12)
    os.close(slave)
    os.close(master)
    assert res.exit_code == 0, res.output
    frames = FrameDecoder().feed(bytes(received))
    assert len(frames) == 50
    np.testing.assert_allclose([f.position_m for f in frames], np.round(pts * 100) / 100, atol=1e-9)
    bad = CliRunner().invoke(app, ["link", "serial", "/dev/does-not-exist", "--from", str(traj)])
    assert bad.exit_code == 2 and "serial port" in bad.output
