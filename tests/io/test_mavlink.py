"""MAVLink on loopback: vision estimates in NED/FRD with their covariance, setpoints, signing."""

from __future__ import annotations

import itertools
import socket
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.errors import ConfigError, IoError
from quadnav.geometry.frames import enu_to_ned, rotation_enu_flu_to_ned_frd
from quadnav.geometry.rotations import Pose
from quadnav.io.mavlink import (
    SIGNING_KEY_ENV,
    MavlinkLink,
    VehicleCommand,
    check_bind,
    covariance_enu_to_ned,
    decode_vehicle_command,
    from_upper_triangle,
    parse_url,
    read_signing_key,
)
from tests.loopback import free_port
from tests.loopback import no_remote_bind as no_remote_bind_fixture

no_remote_bind = no_remote_bind_fixture  # the fixture, for the tests below


def test_urls() -> None:
    assert parse_url("serial:/dev/ttyUSB0:921600") == "/dev/ttyUSB0,921600"
    assert parse_url("udpin:0.0.0.0:14550") == "udpin:0.0.0.0:14550"
    with pytest.raises(IoError, match="serial:DEV:BAUD"):
        parse_url("bluetooth:aa")


def test_covariance_conversion_keeps_what_it_means() -> None:
    """Sampling check: poses drawn from the ENU covariance, converted to NED/FRD Euler angles,
    have the covariance the conversion claims."""
    rng = np.random.default_rng(0)
    R = Rotation.from_euler("ZYX", [0.7, 0.1, -0.2])
    A = rng.normal(size=(6, 6)) * np.array([0.02] * 3 + [0.01] * 3)
    C = A @ A.T
    d = rng.multivariate_normal(np.zeros(6), C, 20000)
    e0 = rotation_enu_flu_to_ned_frd(R).as_euler("ZYX")[::-1]
    eul = np.array(
        [
            rotation_enu_flu_to_ned_frd(Rotation.from_rotvec(x[3:]) * R).as_euler("ZYX")[::-1]
            for x in d[:4000]
        ]
    )
    samples = np.column_stack([enu_to_ned(d[:4000, :3]), eul - e0])
    S, C_ned = np.cov(samples.T), covariance_enu_to_ned(C, R)
    scale = np.sqrt(np.outer(np.diag(C_ned), np.diag(C_ned)))
    # 4000 samples: each entry within 0.1 of its correlation scale (5 standard errors)
    assert np.max(np.abs(S - C_ned) / scale) < 0.1


def test_1000_vision_estimates_at_250_hz_over_loopback() -> None:
    """Paced at 250 Hz (5 to 8 times a vision system's rate: harder, and 4 s rather than 20)."""
    port = free_port()
    rx = MavlinkLink(f"udpin:127.0.0.1:{port}", system=255, component=190)
    tx = MavlinkLink(f"udpout:127.0.0.1:{port}", system=1, component=197)
    rng = np.random.default_rng(1)
    sent = []
    got = []
    t0 = time.monotonic()
    for k in range(1000):
        T = Pose(
            Rotation.from_euler("ZYX", rng.uniform([-3, -0.3, -0.3], [3, 0.3, 0.3])),
            rng.uniform(-5, 5, 3),
        )
        A = rng.normal(size=(6, 6)) * 0.01
        C = A @ A.T + np.eye(6) * 1e-6
        t_ns = 1_000_000_000 + k * 4_000_000
        tx.send_vision_position_estimate(t_ns, T, C, reset_counter=k // 400)
        sent.append((t_ns, T, C, k // 400))
        got += [m for m in rx.poll() if m.get_type() == "VISION_POSITION_ESTIMATE"]
        time.sleep(max(0.0, t0 + (k + 1) * 0.004 - time.monotonic()))  # 250 Hz
    got += [m for m in rx.poll(timeout_s=0.5) if m.get_type() == "VISION_POSITION_ESTIMATE"]
    assert len(got) == 1000  # none lost on loopback
    usec = [m.usec for m in got]
    assert all(b > a for a, b in itertools.pairwise(usec))  # monotonic
    for m, (t_ns, T, C, rc) in zip(got, sent, strict=True):
        assert m.usec == t_ns // 1000 and m.reset_counter == rc
        np.testing.assert_allclose([m.x, m.y, m.z], enu_to_ned(T.p_A_B), atol=1e-5)
        R_ned = Rotation.from_euler("ZYX", [m.yaw, m.pitch, m.roll])
        assert (R_ned.inv() * rotation_enu_flu_to_ned_frd(T.R_A_B)).magnitude() < 1e-5
        np.testing.assert_allclose(
            from_upper_triangle(list(m.covariance)),
            covariance_enu_to_ned(C, T.R_A_B),
            rtol=1e-5,
            atol=1e-10,
        )
    rx.close()
    tx.close()


def test_signing_refuses_unsigned_and_malformed_packets() -> None:
    port = free_port()
    key = bytes(range(32))
    rx = MavlinkLink(f"udpin:127.0.0.1:{port}", system=1, component=1, signing_key=key)
    signed = MavlinkLink(f"udpout:127.0.0.1:{port}", system=255, component=190, signing_key=key)
    unsigned = MavlinkLink(f"udpout:127.0.0.1:{port}", system=254, component=190)
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for _ in range(5):
        unsigned.send_position_setpoint(np.array([9.0, 9.0, 9.0]), 0.0)
        raw.sendto(b"\xfd\x09\x00\x00\x00\xff\xbe\x54\x00\x00garbage!!", ("127.0.0.1", port))
        raw.sendto(
            bytes(np.random.default_rng(0).integers(0, 256, 40, dtype=np.uint8)),
            ("127.0.0.1", port),
        )
    signed.send_position_setpoint(np.array([1.0, 2.0, 3.0]), 0.5)
    msgs = []
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline and not msgs:
        msgs = [
            m for m in rx.poll(timeout_s=0.2) if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"
        ]
    assert len(msgs) == 1  # only the signed one
    m = msgs[0]
    np.testing.assert_allclose([m.x, m.y, m.z], [2.0, 1.0, -3.0], atol=1e-6)
    assert m.get_srcSystem() == 255
    assert rx.stats.refused_unsigned >= 5
    raw.close()
    for link in (rx, signed, unsigned):
        link.close()


def test_listening_beyond_loopback_is_refused_without_binding(no_remote_bind: list[object]) -> None:
    """udpin::PORT, udpin:0.0.0.0:PORT, udp:, tcpin: and a LAN address: refused, nothing bound,
    and the message names --allow-remote; loopback forms (127/8, localhost) pass the check."""
    for url in ("udpin::14550", "udpin:0.0.0.0:14550", "udp:0.0.0.0:14550", "tcpin:0.0.0.0:5760",
                "udpin:192.168.1.20:14550"):  # fmt: skip
        with pytest.raises(IoError, match="--allow-remote") as info:
            MavlinkLink(url)
        assert "not loopback" in str(info.value) and "\n" not in str(info.value)
    assert no_remote_bind == []
    assert check_bind("udpin:0.0.0.0:14550", allow_remote=True) == ("0.0.0.0", 14550)
    assert check_bind("udpin::14550", allow_remote=True) == ("", 14550)
    for url in ("udpin:127.0.0.1:14550", "udpin:127.3.2.1:14550", "udpin:localhost:14550"):
        assert check_bind(url, allow_remote=False) is not None
    assert check_bind("udpout:0.0.0.0:14550", allow_remote=False) is None  # sends, binds nothing
    for url in ("udpin:127.0.0.1:99999", "udpin:14550", "tcpin:127.0.0.1:port",
                "udpin:127.0.0.1:0", "udpout:127.0.0.1:0", "udpout:127.0.0.1:65536",
                "tcp:127.0.0.1:99999", "udpout::14550"):  # fmt: skip
        with pytest.raises(IoError, match=r"--mavlink .*HOST:PORT, PORT from 1 to 65535"):
            check_bind(url, allow_remote=False)
    with pytest.raises(IoError, match="serial:/dev/DEVICE:BAUD"):
        check_bind("serial:/dev/ttyUSB0:0", allow_remote=False)
    assert check_bind("udpout:127.0.0.1:65535", allow_remote=False) is None
    assert no_remote_bind == []


def test_a_second_listener_on_a_port_in_use_is_refused(no_remote_bind: list[object]) -> None:
    """Two vehicles on one UDP port would each get some of the datagrams (pymavlink sets
    SO_REUSEADDR): the second fails with a clear error, whichever of the two came first."""
    from pymavlink import mavutil

    port = free_port()
    first = MavlinkLink(f"udpin:127.0.0.1:{port}", system=1, component=1)
    try:
        with pytest.raises(IoError, match=f"port {port} is already in use"):
            MavlinkLink(f"udpin:127.0.0.1:{port}", system=2, component=1)
        with pytest.raises(OSError):  # a plain pymavlink listener cannot share it either
            mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}")
    finally:
        first.close()
    port2 = free_port()
    other = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port2}")  # another program, first
    try:
        with pytest.raises(IoError, match="already in use"):
            MavlinkLink(f"udpin:127.0.0.1:{port2}")
    finally:
        other.close()
    MavlinkLink(f"udpin:127.0.0.1:{port}").close()  # freed: a new vehicle may take it


def _drain(link: MavlinkLink, n: int = 5) -> None:
    for _ in range(n):
        link.poll(timeout_s=0.05)


def _heard(sock: socket.socket, wait_s: float) -> bytes:
    sock.settimeout(wait_s)
    try:
        return sock.recv(4096)
    except TimeoutError:
        return b""


@pytest.mark.parametrize("signed", [False, True])
def test_a_listener_replies_only_to_peers_that_sent_a_valid_message(signed: bool) -> None:
    """Garbage from a raw socket (and, with signing, an unsigned MAVLink message) does not make
    the listener send there; the sender of a valid (signed) message gets its messages."""
    port = free_port()
    key = bytes(range(32)) if signed else None
    rx = MavlinkLink(f"udpin:127.0.0.1:{port}", system=1, component=1, signing_key=key)
    friend = MavlinkLink(f"udpout:127.0.0.1:{port}", system=255, component=190, signing_key=key)
    unsigned = MavlinkLink(f"udpout:127.0.0.1:{port}", system=254, component=190)
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    raw.bind(("127.0.0.1", 0))
    try:
        raw.sendto(b"not mavlink at all", ("127.0.0.1", port))
        if signed:
            unsigned.heartbeat()
        _drain(rx)
        assert rx.stats.bad_packets >= 1 and rx.peers() == frozenset()
        friend.heartbeat()
        _drain(rx)
        friend_addr = ("127.0.0.1", friend.conn.port.getsockname()[1])
        assert rx.peers() == {friend_addr}
        rx.heartbeat(vehicle=True)
        got = [m for m in friend.poll(timeout_s=1.0) if m.get_type() == "HEARTBEAT"]
        assert len(got) == 1 and got[0].get_srcSystem() == 1
        assert _heard(raw, 0.3) == b""
        if signed:
            assert rx.stats.refused_unsigned >= 1
            assert unsigned.poll(timeout_s=0.3) == []
    finally:
        raw.close()
        for link in (rx, friend, unsigned):
            link.close()


def test_signing_key_from_a_file_the_environment_or_the_command_line(tmp_path: Path) -> None:
    key = bytes(range(40, 72))
    f = tmp_path / "key"
    f.write_text(f"  {key.hex().upper()}\n")
    env = {SIGNING_KEY_ENV: bytes(range(32)).hex()}
    assert read_signing_key(key_hex=None, key_file=f, environ={}) == key
    assert read_signing_key(key_hex=None, key_file=None, environ=env) == bytes(range(32))
    assert read_signing_key(key_hex=None, key_file=f, environ=env) == key  # the option wins
    assert read_signing_key(key_hex=key.hex(), key_file=None, environ=env) == key
    assert read_signing_key(key_hex=None, key_file=None, environ={}) is None
    for kwargs, fragment in (
        ({"key_hex": key.hex(), "key_file": f, "environ": {}}, "not both"),
        ({"key_hex": None, "key_file": tmp_path / "absent", "environ": {}}, "--signing-key-file"),
        ({"key_hex": "abc", "key_file": None, "environ": {}}, "--signing-key: the signing key"),
        ({"key_hex": None, "key_file": None, "environ": {SIGNING_KEY_ENV: ""}}, SIGNING_KEY_ENV),
        ({"key_hex": None, "key_file": None, "environ": {SIGNING_KEY_ENV: "zz" * 32}}, "64 hex"),
    ):
        with pytest.raises(IoError, match=fragment):
            read_signing_key(**kwargs)  # type: ignore[arg-type]
    f.write_text(key.hex()[:-2])  # 31 bytes
    with pytest.raises(ConfigError, match=r"--signing-key-file .*64 hexadecimal digits"):
        read_signing_key(key_hex=None, key_file=f, environ={})


def test_vehicle_commands_decode_from_their_messages() -> None:
    """Arm/disarm, PX4's offboard mode from either message, an unknown command, a non-command."""
    from pymavlink import mavutil

    m = mavutil.mavlink

    def long(cmd: int, p1: float = 0.0, p2: float = 0.0) -> object:
        return m.MAVLink_command_long_message(1, 1, cmd, 0, p1, p2, 0, 0, 0, 0, 0)

    arm = m.MAV_CMD_COMPONENT_ARM_DISARM
    mode = m.MAV_CMD_DO_SET_MODE
    assert decode_vehicle_command(long(arm, 1.0)) == VehicleCommand(
        kind="arm", arm=True, command_id=arm
    )
    assert decode_vehicle_command(long(arm, 0.0)) == VehicleCommand(
        kind="arm", arm=False, command_id=arm
    )
    assert decode_vehicle_command(long(mode, 1.0, 6.0)) == VehicleCommand(
        kind="set_mode", custom_mode=6 << 16, command_id=mode
    )
    assert decode_vehicle_command(m.MAVLink_set_mode_message(1, 1, 6 << 16)) == VehicleCommand(
        kind="set_mode", custom_mode=6 << 16
    )
    takeoff = m.MAV_CMD_NAV_TAKEOFF
    assert decode_vehicle_command(long(takeoff)) == VehicleCommand(
        kind="unsupported", command_id=takeoff
    )
    assert decode_vehicle_command(m.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3)) is None


def test_a_listener_counts_as_sent_only_what_went_to_a_peer() -> None:
    """Issue 21, item 14: a UDP listener writes nothing until a peer speaks, so those messages
    are "not sent", not "sent"; a sender that heard nothing back says "(no peer heard)"."""
    from quadnav.io.mavlink import describe_traffic

    port = free_port()
    rx = MavlinkLink(f"udpin:127.0.0.1:{port}", system=1, component=1)
    tx = MavlinkLink(f"udpout:127.0.0.1:{port}", system=255, component=190)
    try:
        rx.heartbeat(vehicle=True)
        rx.heartbeat(vehicle=True)
        assert rx.stats.sent == {} and rx.stats.unsent_no_peer == 2
        assert rx.describe() == "sent 0 (2 not sent: no peer connected), received 0"
        tx.heartbeat()
        assert tx.describe() == "sent 1 (no peer heard), received 0"
        assert rx.poll(timeout_s=1.0)  # the peer spoke: from now on the listener sends to it
        rx.heartbeat(vehicle=True)
        assert rx.stats.sent == {"HEARTBEAT": 1}
        assert rx.describe() == "sent 1 (2 not sent: before a peer connected), received 1"
        assert tx.poll(timeout_s=1.0)
        assert tx.describe() == "sent 1, received 1"
    finally:
        rx.close()
        tx.close()
    assert describe_traffic({}, {}) == "sent 0, received 0"
