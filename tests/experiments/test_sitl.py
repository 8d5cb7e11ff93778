"""The SITL vehicle flown by an external pymavlink client: arm, offboard, a 2 m square."""

from __future__ import annotations

import os
import socket
import time

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from quadnav.experiments.sitl import PX4_OFFBOARD, SitlVehicle
from tests.loopback import free_port


def setpoint(gcs, x_n: float, y_e: float, z_d: float) -> None:
    m = mavutil.mavlink
    mask = 0b0000_1101_1111_1000  # position and yaw only
    gcs.mav.set_position_target_local_ned_send(
        0, 1, 1, m.MAV_FRAME_LOCAL_NED, mask, x_n, y_e, z_d, 0, 0, 0, 0, 0, 0, 0.0, 0
    )


def test_external_client_flies_a_square_in_offboard() -> None:
    port = free_port()
    sitl = SitlVehicle(url=f"udpin:127.0.0.1:{port}")
    sitl.start()
    gcs = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}", source_system=255, source_component=190, dialect="common"
    )
    try:
        gcs.mav.heartbeat_send(
            mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0
        )
        hb = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=5)
        assert hb is not None and hb.type == mavutil.mavlink.MAV_TYPE_QUADROTOR
        # setpoints first (PX4 refuses offboard without a stream), then mode, then arm
        for _ in range(10):
            setpoint(gcs, 0, 0, -1.5)
            time.sleep(0.05)
        gcs.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 6, 0, 0, 0, 0, 0)
        gcs.mav.command_long_send(
            1, 1, mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0
        )
        corners_ned = [
            (0, 0, -1.5),
            (0, 2, -1.5),
            (2, 2, -1.5),
            (2, 0, -1.5),
            (0, 0, -1.5),
        ]  # N, E, D
        reached = []
        for n, e, d in corners_ned:
            t_end = time.monotonic() + 8.0
            best = np.inf
            while time.monotonic() < t_end:
                setpoint(gcs, n, e, d)  # 20 Hz stream
                time.sleep(0.05)
                while (msg := gcs.recv_match(blocking=False)) is not None:
                    if msg.get_type() == "HEARTBEAT":
                        assert msg.custom_mode == PX4_OFFBOARD
                p = sitl.truth_log[-1][1]  # true position, ENU
                best = min(best, float(np.linalg.norm(p - np.array([e, n, -d]))))
                if best < 0.1:
                    break
            reached.append(best)
        assert max(reached) <= 0.2, reached
        assert sitl.armed and sitl.offboard
        # setpoints stop: the vehicle leaves offboard and holds
        time.sleep(1.0)
        assert not sitl.offboard
        p_hold = sitl.truth_log[-1][1]
        assert np.linalg.norm(p_hold - np.array([0.0, 0.0, 1.5])) < 0.3
    finally:
        sitl.stop()
        gcs.close()


def test_signing_enabled_sitl_ignores_unsigned_and_malformed_packets() -> None:
    port = free_port()
    key = bytes(range(100, 132))
    sitl = SitlVehicle(url=f"udpin:127.0.0.1:{port}", signing_key=key)
    sitl.start()
    intruder = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}", source_system=200, dialect="common"
    )
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rng = np.random.default_rng(0)
    try:
        for _ in range(20):
            setpoint(intruder, 5, 5, -3)
            intruder.mav.command_long_send(
                1, 1, mavutil.mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 6, 0, 0, 0, 0, 0
            )
            intruder.mav.command_long_send(
                1, 1, mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0
            )
            raw.sendto(rng.integers(0, 256, 60, dtype=np.uint8).tobytes(), ("127.0.0.1", port))
            raw.sendto(
                b"\xfd\x1c\x00\x00\x07\xc8\xbe\x54\x00\x00" + bytes(10), ("127.0.0.1", port)
            )  # truncated
            time.sleep(0.05)
        t_end = time.monotonic() + 15.0  # (ends as soon as they are counted)
        while sitl.link.stats.refused_unsigned < 20 and time.monotonic() < t_end:
            time.sleep(0.05)
        assert sitl.link.stats.refused_unsigned >= 20
        assert not sitl.armed and not sitl.offboard and sitl.setpoint is None
        # the key holder is obeyed
        friend = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", source_system=255, dialect="common"
        )
        friend.setup_signing(key, sign_outgoing=True)
        # a loaded machine may run the vehicle's loop late: CI with two busy workers once took
        # more than 5 s (the wait ends as soon as the vehicle is armed)
        t_end = time.monotonic() + 15.0
        while not sitl.armed and time.monotonic() < t_end:
            friend.mav.command_long_send(
                1, 1, mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0
            )
            time.sleep(0.1)
        assert sitl.armed
        friend.close()
    finally:
        sitl.stop()
        intruder.close()
        raw.close()


def test_signed_sitl_streams_telemetry_only_to_signed_peers() -> None:
    """One non-MAVLink datagram and an unsigned heartbeat used to register their sockets for the
    vehicle's 50 Hz telemetry; now only the peer that sent a valid signed message gets it."""
    port = free_port()
    key = bytes(range(7, 39))
    sitl = SitlVehicle(url=f"udpin:127.0.0.1:{port}", signing_key=key)
    sitl.start()
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    raw.bind(("127.0.0.1", 0))
    intruder = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=200)
    friend = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255)
    friend.setup_signing(key, sign_outgoing=True)
    try:
        raw.sendto(b"hello vehicle, where are you?", ("127.0.0.1", port))
        intruder.mav.heartbeat_send(
            mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0
        )
        t_end = (
            time.monotonic() + 5.0
        )  # the vehicle's loop has read both (a loaded machine runs it late)
        while (
            sitl.link.stats.bad_packets < 1 or sitl.link.stats.refused_unsigned < 1
        ) and time.monotonic() < t_end:
            time.sleep(0.02)
        assert sitl.link.stats.bad_packets >= 1 and sitl.link.stats.refused_unsigned >= 1
        friend.mav.heartbeat_send(
            mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0
        )
        att = friend.recv_match(type="ATTITUDE", blocking=True, timeout=5)
        assert att is not None and att.get_srcSystem() == 1  # the key holder hears the vehicle
        # by now the others would have had ~25 ATTITUDE messages each
        raw.settimeout(0.5)
        with pytest.raises(TimeoutError):
            raw.recv(4096)
        assert intruder.recv_match(blocking=True, timeout=0.5) is None
        assert sitl.link.peers() == {("127.0.0.1", friend.port.getsockname()[1])}
    finally:
        sitl.stop()
        for c in (intruder, friend):
            c.close()
        raw.close()


def test_run_refuses_a_duration_that_would_end_at_once_or_never() -> None:
    from quadnav.errors import ExperimentError

    sitl = SitlVehicle(url=f"udpin:127.0.0.1:{free_port()}")
    try:
        for bad in (-5.0, 0.0, float("nan"), float("inf")):  # -5 first: nan used to never return
            with pytest.raises(ExperimentError, match="duration_s"):
                sitl.run(bad)
        assert sitl.truth_log == []  # not a single step was flown
    finally:
        sitl.stop()
