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


def test_sender_paces_a_faster_estimate_to_its_rate_and_counts_what_it_cannot_send() -> None:
    """Positions offered at 30 Hz for 2 s leave at 10 Hz (every third, 20 frames); a NaN and a
    position beyond 6 digits of centimetres are not sent, counted, and do not delay the next."""
    from quadnav.io.serial_frame import FrameSender

    out: list[bytes] = []
    s = FrameSender(out.append, rate_hz=10.0)
    period = 1_000_000_000 // 30
    for k in range(60):
        s.offer(k * period, (0.01 * k, 0.0, 1.2))
    assert s.sent == 20 and len(out) == 20
    assert out[1] == encode(0.03, 0.0, 1.2)  # the third offer: the first due after 0.1 s
    t = 60 * period + 200_000_000
    assert s.offer(t, (float("nan"), 0.0, 0.0)) is None
    assert s.offer(t, (1e5, 0.0, 0.0)) is None
    assert s.unsendable == 2
    assert s.offer(t, (1.0, 2.0, 3.0)) == b"X100Y200Z300F"
    with pytest.raises(IoError, match="send rate"):
        FrameSender(out.append, rate_hz=0.0)


def test_receiver_over_a_pty_link_gives_the_positions_and_the_euler_velocity_under_noise() -> None:
    """Frames of a 0.3 m/s ramp through a pseudo-terminal with random bytes between them (no
    'X' among them: noise that would start a frame is the decoder's tests' matter): each
    position is decoded to the centimetre, the velocity is the thesis's difference over 0.1 s,
    and the garbage is counted byte for byte."""
    from quadnav.io.serial_frame import FrameReceiver, FrameSender, PtyLink

    rng = np.random.default_rng(3)
    noise = bytes(b for b in range(256) if b != ord("X"))
    junk_total = 0
    with PtyLink() as link:
        rx = FrameReceiver()
        tx = FrameSender(link.write)
        for k in range(40):
            junk = bytes(rng.choice(list(noise), size=int(rng.integers(0, 6))))
            link.write(junk)
            junk_total += len(junk)
            p = (0.03 * k, -0.5 + 0.012 * k, 1.2)
            tx.offer(k * 100_000_000, p)
            assert rx.feed(link.read()) == 1
            assert rx.position_m == pytest.approx(p, abs=0.005)
            if k > 0:
                assert rx.velocity_m_s[0] == pytest.approx(0.3, abs=0.1 + 1e-9)  # 1 cm / 0.1 s
    assert rx.decoder.frames == 40
    # a byte of noise inside no frame is garbage; one after F but before the next X, too
    assert rx.decoder.garbage_bytes == junk_total
