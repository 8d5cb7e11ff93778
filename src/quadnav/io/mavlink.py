"""MAVLink to the autopilot, on pymavlink (MAVLink 2, the common dialect).

Connection strings as MAVLink tools write them: ``udpin:127.0.0.1:14550``,
``udpout:127.0.0.1:14540``, ``tcp:127.0.0.1:5760``, ``serial:/dev/ttyUSB0:921600`` (or a bare
device path). ENU/FLU become NED/FRD here and only here: positions and velocities through
``enu_to_ned``, attitudes through ``rotation_enu_flu_to_ned_frd``, covariances through the same
linear maps. Message signing (MAVLink 2) is an option: with a key, outgoing messages are signed
and unsigned incoming ones are refused unless ``allow_unsigned``.

A listening URL (``udpin:``, ``udp:``, ``tcpin:``) binds loopback only unless ``allow_remote``,
and refuses a port another program already holds (pymavlink would share it). A UDP listener
sends its telemetry only to peers that sent it a valid MAVLink message (with signing, a valid
signed one), not to whatever address a datagram came from.
"""

from __future__ import annotations

import errno
import functools
import ipaddress
import os
import socket
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

os.environ.setdefault("MAVLINK20", "1")

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import ConfigError, IoError
from quadnav.geometry.frames import (
    enu_to_ned,
    ned_to_enu,
    rotation_enu_flu_to_ned_frd,
    rotation_ned_frd_to_enu_flu,
)
from quadnav.geometry.rotations import Pose
from quadnav.messages import OdometrySample

__all__ = [
    "SIGNING_KEY_ENV",
    "MavlinkLink",
    "ReceivedState",
    "VehicleCommand",
    "check_bind",
    "covariance_enu_to_ned",
    "covariance_ned_to_enu",
    "decode_odometry",
    "decode_vehicle_command",
    "describe_traffic",
    "parse_url",
    "read_signing_key",
    "signing_key_file_warning",
    "upper_triangle",
    "velocity_covariance_enu_to_frd",
]

FloatArray = NDArray[np.float64]
_M = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # ENU <-> NED (its own inverse)


NETWORK_SCHEMES = ("udpin:", "udpout:", "udp:", "tcpin:", "tcp:")
LISTENERS = ("udpin:", "udp:", "tcpin:")  # the schemes that bind a local port
SIGNING_KEY_ENV = "QUADNAV_SIGNING_KEY"
_URL_FORMS = "udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT or serial:DEV:BAUD"


def parse_url(url: str) -> str:
    """pymavlink's connection string for ``url`` (``serial:/dev/x:baud`` -> ``/dev/x,baud``),
    after checking it: the one place a ``--mavlink`` endpoint is parsed. A network URL needs a
    port from 1 to 65535 (and a host, but for a listener, where none means every interface);
    a serial one a device and a positive baud rate. A bad one is a one-line
    :class:`~quadnav.errors.IoError` naming ``--mavlink``."""
    if url.startswith("serial:"):
        dev, _, baud = url[len("serial:") :].rpartition(":")
        if not dev or not baud.isdigit() or int(baud) == 0:
            raise IoError(f"--mavlink {url!r}: expected serial:/dev/DEVICE:BAUD, BAUD above 0")
        return f"{dev},{baud}"
    if url.startswith("/dev/"):
        return url
    scheme = next((s for s in NETWORK_SCHEMES if url.startswith(s)), None)
    if scheme is None:
        raise IoError(f"--mavlink {url!r}: use {_URL_FORMS}")
    _host_port(url, scheme)
    return url


def _host_port(url: str, scheme: str) -> tuple[str, int]:
    """The host and port of a network URL, the port from 1 to 65535."""
    host, sep, port_s = url[len(scheme) :].rpartition(":")
    form = f"expected {scheme}HOST:PORT, PORT from 1 to 65535"
    if not sep or not port_s.isdigit() or ":" in host or (not host and scheme not in LISTENERS):
        raise IoError(f"--mavlink {url!r}: {form}")
    port = int(port_s)
    if not 1 <= port <= 65535:
        raise IoError(f"--mavlink {url!r}: port {port} is out of range; {form}")
    return host, port


def check_bind(url: str, *, allow_remote: bool) -> tuple[str, int] | None:
    """Check any endpoint (:func:`parse_url`); for a listening URL, the ``(host, port)`` it
    binds, a loopback host unless ``allow_remote`` (an empty host or ``0.0.0.0`` is every
    interface). ``None`` for a URL that does not listen. Nothing is bound here."""
    parse_url(url)
    scheme = next((s for s in LISTENERS if url.startswith(s)), None)
    if scheme is None:
        return None
    host, port = _host_port(url, scheme)
    if not allow_remote and not _is_loopback(host, url):
        where = f"host {host!r}" if host else "an empty host (every interface)"
        raise IoError(
            f"--mavlink {url!r}: {where} is not loopback, anyone on the network could "
            "command the vehicle; bind 127.0.0.1, or pass --allow-remote to mean it"
        )
    return host, port


def _is_loopback(host: str, url: str) -> bool:
    if not host:
        return False
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # a host name: every address it resolves to must be loopback
        try:
            infos = socket.getaddrinfo(host, None, socket.AF_INET)
        except OSError:
            raise IoError(f"--mavlink {url!r}: cannot resolve host {host!r}") from None
        return all(ipaddress.ip_address(str(i[4][0])).is_loopback for i in infos)


def _check_port_free(host: str, port: int, url: str) -> None:
    """Refuse a UDP port another socket holds (pymavlink sets SO_REUSEADDR and would share it:
    two vehicles on one port each get some of the datagrams)."""
    probe = socket.socket(
        socket.AF_INET, socket.SOCK_DGRAM
    )  # no SO_REUSEADDR: any holder conflicts
    try:
        probe.bind((host, port))
    except OSError as exc:
        raise IoError(_in_use(url, port, exc)) from None
    finally:
        probe.close()


def _in_use(url: str, port: int, exc: OSError) -> str:
    if exc.errno == errno.EADDRINUSE:
        return f"MAVLink {url}: port {port} is already in use (another vehicle or program holds it)"
    return f"MAVLink {url}: {exc}"


def read_signing_key(
    *, key_hex: str | None, key_file: Path | None, environ: Mapping[str, str]
) -> bytes | None:
    """The 32-byte MAVLink 2 signing key, as 64 hexadecimal digits from ``--signing-key-file``
    (a file), ``--signing-key`` (the command line, visible in ``ps``) or the environment
    variable ``QUADNAV_SIGNING_KEY``, in that order; ``None`` when none is given."""
    if key_hex is not None and key_file is not None:
        raise ConfigError(
            "give the signing key once: --signing-key-file or --signing-key, not both"
        )
    if key_file is not None:
        try:
            text = key_file.read_text(encoding="ascii")
        except (OSError, UnicodeDecodeError) as exc:
            raise IoError(f"--signing-key-file {key_file}: cannot read it ({exc})") from None
        return _key_from_hex(text, f"--signing-key-file {key_file}")
    if key_hex is not None:
        return _key_from_hex(key_hex, "--signing-key")
    if SIGNING_KEY_ENV in environ:
        return _key_from_hex(environ[SIGNING_KEY_ENV], SIGNING_KEY_ENV)
    return None


def signing_key_file_warning(key_file: Path) -> str | None:
    """As ssh does for a private key: a one-line warning when the signing key file may be read
    or written by other users (any group or other permission bit), naming the file and its
    mode; ``None`` for a file only its owner can use."""
    try:
        mode = key_file.stat().st_mode & 0o777
    except OSError:
        return None  # reading it fails with its own message
    if not mode & 0o077:
        return None
    return (
        f"warning: UNPROTECTED KEY FILE: --signing-key-file {key_file} has mode {mode:04o}, "
        f"other users may read the key that signs commands to the vehicle; chmod 600 {key_file}"
    )


def _key_from_hex(text: str, what: str) -> bytes:
    digits = text.strip()
    try:
        key = bytes.fromhex(digits)
    except ValueError:
        key = b""
    if len(key) != 32:
        raise ConfigError(f"{what}: the signing key must be 64 hexadecimal digits (32 bytes)")
    return key


def upper_triangle(C: FloatArray) -> list[float]:
    """The 21 entries of a 6x6 covariance's upper triangle, row by row (MAVLink's layout)."""
    iu = np.triu_indices(6)
    return [float(v) for v in np.asarray(C)[iu]]


def from_upper_triangle(v: list[float]) -> FloatArray:
    C = np.zeros((6, 6))
    iu = np.triu_indices(6)
    C[iu] = v
    return C + np.triu(C, 1).T


def _mavlink_dialect() -> Any:
    """pymavlink's common dialect (its constants), imported when first needed."""
    from pymavlink import mavutil  # type: ignore[import-untyped]

    return mavutil.mavlink


def _symmetric(C: FloatArray) -> FloatArray:
    return np.asarray(0.5 * (C + C.T), dtype=np.float64)


def _pose_covariance_map(R_ENU_FLU: Rotation) -> FloatArray:
    """The linear map (6x6) of a pose error [position ENU, attitude error in the world] onto
    MAVLink's [x, y, z NED, roll, pitch, yaw of the FRD body] (the attitude part the derivative
    of the NED/FRD Euler angles, by central differences)."""
    J = np.zeros((3, 3))
    for k in range(3):
        d = np.zeros(3)
        d[k] = 1e-6
        ep = rotation_enu_flu_to_ned_frd(Rotation.from_rotvec(d) * R_ENU_FLU).as_euler("ZYX")
        em = rotation_enu_flu_to_ned_frd(Rotation.from_rotvec(-d) * R_ENU_FLU).as_euler("ZYX")
        J[:, k] = (np.remainder(ep - em + np.pi, 2 * np.pi) - np.pi)[::-1]
    J /= 2e-6
    T = np.zeros((6, 6))
    T[0:3, 0:3] = _M
    T[3:6, 3:6] = J
    return T


def covariance_enu_to_ned(C_enu: FloatArray, R_ENU_FLU: Rotation) -> FloatArray:
    """A pose covariance [position ENU, attitude error] to MAVLink's [x, y, z NED, roll, pitch,
    yaw]: the position block through ENU->NED, the attitude (a small rotation in the world,
    ``R_true = Exp(dtheta) R``) through the derivative of the NED/FRD Euler angles."""
    T = _pose_covariance_map(R_ENU_FLU)
    return _symmetric(T @ np.asarray(C_enu, dtype=np.float64) @ T.T)


def covariance_ned_to_enu(C_ned: FloatArray, R_ENU_FLU: Rotation) -> FloatArray:
    """The inverse of :func:`covariance_enu_to_ned` (what a receiver of ODOMETRY recovers)."""
    T_inv = np.linalg.inv(_pose_covariance_map(R_ENU_FLU))
    return _symmetric(T_inv @ np.asarray(C_ned, dtype=np.float64) @ T_inv.T)


def velocity_covariance_enu_to_frd(C_enu: FloatArray, R_ENU_FLU: Rotation) -> FloatArray:
    """A world (ENU) velocity covariance (3x3) in the FRD body's axes, ODOMETRY's velocity
    frame: ``C_FRD = R_NED_FRD^T M C M^T R_NED_FRD``."""
    A = rotation_enu_flu_to_ned_frd(R_ENU_FLU).as_matrix().T @ _M
    return _symmetric(A @ np.asarray(C_enu, dtype=np.float64) @ A.T)


def decode_odometry(msg: Any, *, source: str = "vio") -> OdometrySample:
    """An ODOMETRY message (MAV_FRAME_LOCAL_FRD, body MAV_FRAME_BODY_FRD) back in quadnav's
    frames: pose ENU/FLU, world velocity, the covariances (pose as [position, world attitude
    error], velocity in the world), reset counter and quality. A message another frame or with
    no covariance is an :class:`~quadnav.errors.IoError`."""
    m = _mavlink_dialect()
    if (msg.frame_id, msg.child_frame_id) != (m.MAV_FRAME_LOCAL_FRD, m.MAV_FRAME_BODY_FRD):
        raise IoError(
            f"ODOMETRY in frames {msg.frame_id}/{msg.child_frame_id}: only LOCAL_FRD/BODY_FRD"
        )
    w, x, y, z = msg.q
    R_ned = Rotation.from_quat([x, y, z, w])
    R = rotation_ned_frd_to_enu_flu(R_ned)
    cov = np.array(msg.pose_covariance, dtype=np.float64)
    vcov = np.array(msg.velocity_covariance, dtype=np.float64)
    if not (np.isfinite(cov).all() and np.isfinite(vcov[[0, 1, 2, 6, 7, 11]]).all()):
        raise IoError("ODOMETRY without a pose or velocity covariance")
    C_v_frd = from_upper_triangle(list(vcov))[0:3, 0:3]
    to_enu = _M @ R_ned.as_matrix()  # FRD body axes -> NED -> ENU
    return OdometrySample(
        t_ns=int(msg.time_usec) * 1000,
        p_W_B=ned_to_enu(np.array([msg.x, msg.y, msg.z], dtype=np.float64)),
        q_W_B_xyzw=R.as_quat(),
        v_W_B=to_enu @ np.array([msg.vx, msg.vy, msg.vz], dtype=np.float64),
        cov_pose=covariance_ned_to_enu(from_upper_triangle(list(cov)), R),
        cov_v=_symmetric(to_enu @ C_v_frd @ to_enu.T),
        reset_counter=int(msg.reset_counter),
        quality=max(0, int(msg.quality)),
        source=source,
    )


def _connect(mavutil: Any, url: str, system: int, component: int, *, allow_remote: bool) -> Any:
    """pymavlink's connection for ``url``; a UDP listener is a :func:`_peer_udp_class` that
    holds its port alone."""
    bind = check_bind(url, allow_remote=allow_remote)
    try:
        if bind is not None and not url.startswith("tcpin:"):
            host, port = bind
            _check_port_free(host, port, url)
            mavutil.set_dialect("common")
            conn = _peer_udp_class(mavutil)(
                f"{host}:{port}", input=True, source_system=system, source_component=component
            )
            # later binders conflict with us, even those that set SO_REUSEADDR themselves
            conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 0)
            return conn
        return mavutil.mavlink_connection(
            parse_url(url), source_system=system, source_component=component, dialect="common"
        )
    except OSError as exc:
        raise IoError(_in_use(url, bind[1] if bind else 0, exc)) from None
    except IoError:
        raise
    except Exception as exc:  # pymavlink raises SerialException, ValueError...
        raise IoError(f"MAVLink {url}: {exc}") from None


@functools.cache
def _peer_udp_class(mavutil: Any) -> type[Any]:
    """pymavlink's UDP listener, except that it replies only to peers: senders of a valid
    MAVLink message (a valid signed one once ``require_signed``), not every address a datagram
    came from. A message is credited to its datagram's sender only if it began in that datagram."""

    class PeerUdp(mavutil.mavudp):  # type: ignore[misc]
        require_signed = False
        sender: tuple[str, int] | None = None
        sender_clean = False  # the parser held nothing from an earlier datagram

        def recv(self, n: int | None = None) -> bytes | str:
            try:
                data, addr = self.port.recvfrom(mavutil.UDP_MAX_PACKET_LEN)
            except OSError as exc:
                if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.ECONNREFUSED):
                    return ""
                raise
            self.sender, self.sender_clean = addr, self.mav.buf_len() == 0
            return bytes(data)

        def recv_msg(self) -> Any:
            self.pre_message()
            m = self.mav.parse_char(b"")  # the rest of the last datagram first
            if m is None:
                s = self.recv()
                if not s:
                    return None
                if self.first_byte:
                    self.auto_mavlink_version(s)
                m = self.mav.parse_char(s)
            if m is not None:
                self._admit(m)
                self.post_message(m)
            return m

        def _admit(self, m: Any) -> None:
            if m.get_type() == "BAD_DATA" or not self.sender_clean or self.sender is None:
                return
            if self.require_signed and not m.get_signed():
                return
            self.clients.add(self.sender)
            self.clients_last_alive[self.sender] = time.time()

    return PeerUdp


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleCommand:
    """A command to a vehicle: arm/disarm or a mode change, from COMMAND_LONG or SET_MODE.

    ``command_id`` is COMMAND_LONG's command (it wants a COMMAND_ACK); None for SET_MODE."""

    kind: Literal["arm", "set_mode", "unsupported"]
    arm: bool = False
    custom_mode: int = 0
    command_id: int | None = None


def decode_vehicle_command(msg: Any) -> VehicleCommand | None:
    """What a vehicle is told to do by ``msg``; None for a message that is not a command.
    MAV_CMD_DO_SET_MODE carries PX4's custom main mode in ``param2`` (bits 16-23 of the mode)."""
    m = _mavlink_dialect()
    name = msg.get_type()
    if name == "SET_MODE":
        return VehicleCommand(kind="set_mode", custom_mode=int(msg.custom_mode))
    if name != "COMMAND_LONG":
        return None
    cid = int(msg.command)
    if cid == m.MAV_CMD_COMPONENT_ARM_DISARM:
        return VehicleCommand(kind="arm", arm=msg.param1 > 0.5, command_id=cid)
    if cid == m.MAV_CMD_DO_SET_MODE:
        return VehicleCommand(kind="set_mode", custom_mode=int(msg.param2) << 16, command_id=cid)
    return VehicleCommand(kind="unsupported", command_id=cid)


@dataclass
class ReceivedState:
    """What a vehicle told us, in ENU/FLU."""

    heartbeats: int = 0
    armed: bool = False
    custom_mode: int = 0
    attitude: Rotation | None = None
    position_enu: FloatArray | None = None
    velocity_enu: FloatArray | None = None
    odometry: Pose | None = None
    t_boot_ms: int = 0


@dataclass
class LinkStats:
    """What a link did: ``sent`` counts the messages written towards a peer (a UDP sender's
    address, a serial port, a connected TCP client); ``unsent_no_peer`` a listener's messages
    while no peer had spoken to it (written nowhere)."""

    sent: dict[str, int] = field(default_factory=dict)
    received: dict[str, int] = field(default_factory=dict)
    refused_unsigned: int = 0
    bad_packets: int = 0
    unsent_no_peer: int = 0


def describe_traffic(
    sent: Mapping[str, int], received: Mapping[str, int], *, unsent_no_peer: int = 0
) -> str:
    """The terminal's words for a link's traffic, honest about UDP: a datagram "sent" to an
    address nobody listens on is lost without a word, so a link that heard nothing back says
    so ("sent 82 (no peer heard)"), and a listener's messages with no peer are not "sent"."""
    n_sent, n_received = sum(sent.values()), sum(received.values())
    text = f"sent {n_sent}"
    if unsent_no_peer:
        when = "no peer connected" if n_sent == 0 else "before a peer connected"
        text += f" ({unsent_no_peer} not sent: {when})"
    elif n_sent and not n_received:
        text += " (no peer heard)"
    return f"{text}, received {n_received}"


class MavlinkLink:
    """One MAVLink endpoint (a companion computer, a ground station, or our simulated vehicle)."""

    def __init__(
        self,
        url: str,
        *,
        system: int = 1,
        component: int = 197,  # MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY
        signing_key: bytes | None = None,
        allow_unsigned: bool = False,
        allow_remote: bool = False,
    ) -> None:
        from pymavlink import mavutil

        self._mavutil = mavutil
        if signing_key is not None and len(signing_key) != 32:
            raise IoError("MAVLink signing key must be 32 bytes")
        self.conn = _connect(mavutil, url, system, component, allow_remote=allow_remote)
        self.url = url
        self.mav = self.conn.mav
        self.stats = LinkStats()
        self.state = ReceivedState()
        self.t0 = time.monotonic()
        if signing_key is not None:
            if isinstance(self.conn, _peer_udp_class(mavutil)):
                self.conn.require_signed = True

            def allow(_mav: Any, _msg_id: int) -> bool:
                if not allow_unsigned:
                    self.stats.refused_unsigned += 1
                return allow_unsigned

            self.conn.setup_signing(signing_key, sign_outgoing=True, allow_unsigned_callback=allow)

    def peers(self) -> frozenset[tuple[str, int]]:
        """Where a UDP listener sends: the peers that sent it a valid (with signing, signed)
        message. Empty for other links."""
        if isinstance(self.conn, _peer_udp_class(self._mavutil)):
            return frozenset(self.conn.clients)
        return frozenset()

    def _count(self, name: str) -> None:
        if self._has_peer():
            self.stats.sent[name] = self.stats.sent.get(name, 0) + 1
        else:
            self.stats.unsent_no_peer += 1

    def _has_peer(self) -> bool:
        """Whether a message written now goes anywhere: a listener writes only to its peers
        (UDP) or its connected client (TCP); a sender and a serial port always write."""
        if isinstance(self.conn, _peer_udp_class(self._mavutil)):
            return bool(self.conn.clients)
        if isinstance(self.conn, self._mavutil.mavtcpin):
            return self.conn.port is not None
        return True

    def describe(self) -> str:
        """:func:`describe_traffic` of this link's counts."""
        s = self.stats
        return describe_traffic(s.sent, s.received, unsent_no_peer=s.unsent_no_peer)

    def boot_ms(self) -> int:
        return int((time.monotonic() - self.t0) * 1e3)

    # -- sending -----------------------------------------------------------------------------
    def heartbeat(
        self, *, vehicle: bool = False, armed: bool = False, custom_mode: int = 0
    ) -> None:
        m = self._mavutil.mavlink
        if vehicle:
            base = m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (
                m.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
            )
            self.mav.heartbeat_send(
                m.MAV_TYPE_QUADROTOR, m.MAV_AUTOPILOT_PX4, base, custom_mode, m.MAV_STATE_ACTIVE
            )
        else:
            self.mav.heartbeat_send(
                m.MAV_TYPE_ONBOARD_CONTROLLER, m.MAV_AUTOPILOT_INVALID, 0, 0, m.MAV_STATE_ACTIVE
            )
        self._count("HEARTBEAT")

    def send_vision_position_estimate(
        self, t_ns: int, T_ENU_FLU: Pose, cov_enu: FloatArray, reset_counter: int = 0
    ) -> None:
        """VISION_POSITION_ESTIMATE: position NED, roll/pitch/yaw of the FRD body, covariance."""
        p = enu_to_ned(T_ENU_FLU.p_A_B)
        rpy = rotation_enu_flu_to_ned_frd(T_ENU_FLU.R_A_B).as_euler("ZYX")[::-1]
        C = covariance_enu_to_ned(cov_enu, T_ENU_FLU.R_A_B)
        self.mav.vision_position_estimate_send(
            int(t_ns // 1000),
            *map(float, p),
            *map(float, rpy),
            covariance=upper_triangle(C),
            reset_counter=int(reset_counter) % 256,
        )
        self._count("VISION_POSITION_ESTIMATE")

    def send_odometry(
        self,
        t_ns: int,
        T_ENU_FLU: Pose,
        cov_enu: FloatArray,
        v_enu: FloatArray | None = None,
        reset_counter: int = 0,
        *,
        cov_v_enu: FloatArray | None = None,
        quality: int = 100,
        estimator: Literal["vision", "vio"] = "vision",
    ) -> None:
        """ODOMETRY in MAV_FRAME_LOCAL_FRD with the body in MAV_FRAME_BODY_FRD, quaternion w
        first, the velocity in the body's FRD axes. Covariances as MAVLink's 21-element upper
        triangles: the pose's [x, y, z, roll, pitch, yaw] (:func:`covariance_enu_to_ned`), the
        velocity's [vx, vy, vz, rates] with the rates unknown (NaN; the whole of it NaN first
        without ``cov_v_enu``). ``estimator``: MAV_ESTIMATOR_TYPE_VISION or _VIO."""
        m = self._mavutil.mavlink
        R = rotation_enu_flu_to_ned_frd(T_ENU_FLU.R_A_B)
        x, y, z, w = R.as_quat()
        p = enu_to_ned(T_ENU_FLU.p_A_B)
        v_body = (
            R.apply(enu_to_ned(v_enu), inverse=True) if v_enu is not None else np.full(3, np.nan)
        )
        vel_cov = [float("nan")] + [0.0] * 20  # NaN first: unknown
        if cov_v_enu is not None:
            C6 = np.zeros((6, 6))
            C6[0:3, 0:3] = velocity_covariance_enu_to_frd(cov_v_enu, T_ENU_FLU.R_A_B)
            C6[3:6, 3:6] = np.diag([np.nan] * 3)
            vel_cov = upper_triangle(C6)
        kind = m.MAV_ESTIMATOR_TYPE_VIO if estimator == "vio" else m.MAV_ESTIMATOR_TYPE_VISION
        self.mav.odometry_send(
            int(t_ns // 1000),
            m.MAV_FRAME_LOCAL_FRD,
            m.MAV_FRAME_BODY_FRD,
            *map(float, p),
            [float(w), float(x), float(y), float(z)],
            *map(float, v_body),
            float("nan"),
            float("nan"),
            float("nan"),
            upper_triangle(covariance_enu_to_ned(cov_enu, T_ENU_FLU.R_A_B)),
            vel_cov,
            int(reset_counter) % 256,
            kind,
            int(quality),
        )
        self._count("ODOMETRY")

    def send_odometry_sample(self, odo: OdometrySample) -> None:
        """An external-odometry sample (a VIO's) as PX4 takes it from a companion computer:
        ODOMETRY with its covariances, reset counter and quality, MAV_ESTIMATOR_TYPE_VIO."""
        self.send_odometry(
            odo.t_ns,
            Pose(Rotation.from_quat(odo.q_W_B_xyzw), odo.p_W_B),
            odo.cov_pose,
            odo.v_W_B,
            odo.reset_counter,
            cov_v_enu=odo.cov_v,
            quality=odo.quality,
            estimator="vio",
        )

    def send_position_setpoint(
        self,
        p_enu: FloatArray,
        yaw_enu_rad: float,
        target_system: int = 1,
        target_component: int = 1,
    ) -> None:
        """SET_POSITION_TARGET_LOCAL_NED: position and yaw only (PX4 needs them at > 2 Hz)."""
        m = self._mavutil.mavlink
        mask = (
            m.POSITION_TARGET_TYPEMASK_VX_IGNORE
            | m.POSITION_TARGET_TYPEMASK_VY_IGNORE
            | m.POSITION_TARGET_TYPEMASK_VZ_IGNORE
            | m.POSITION_TARGET_TYPEMASK_AX_IGNORE
            | m.POSITION_TARGET_TYPEMASK_AY_IGNORE
            | m.POSITION_TARGET_TYPEMASK_AZ_IGNORE
            | m.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
        )
        p = enu_to_ned(np.asarray(p_enu, dtype=np.float64))
        yaw_ned = float(np.pi / 2 - yaw_enu_rad)
        self.mav.set_position_target_local_ned_send(
            self.boot_ms(),
            target_system,
            target_component,
            m.MAV_FRAME_LOCAL_NED,
            mask,
            *map(float, p),
            0,
            0,
            0,
            0,
            0,
            0,
            yaw_ned,
            0,
        )
        self._count("SET_POSITION_TARGET_LOCAL_NED")

    def ack_command(self, command: VehicleCommand) -> None:
        """COMMAND_ACK for a COMMAND_LONG: accepted, or unsupported; nothing for SET_MODE."""
        if command.command_id is None:
            return
        m = self._mavutil.mavlink
        ok = command.kind != "unsupported"
        result = m.MAV_RESULT_ACCEPTED if ok else m.MAV_RESULT_UNSUPPORTED
        self.mav.command_ack_send(command.command_id, result)
        self._count("COMMAND_ACK")

    # -- receiving ---------------------------------------------------------------------------
    def poll(self, timeout_s: float = 0.0) -> list[Any]:
        """Read what has arrived (waiting up to ``timeout_s`` for the first message); update
        :attr:`state`; return the messages."""
        out: list[Any] = []
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                blocking = timeout_s > 0 and not out
                # (pymavlink's recv_match gives up before reading when given timeout=0)
                wait = max(deadline - time.monotonic(), 0.001) if blocking else None
                msg = self.conn.recv_match(blocking=blocking, timeout=wait)
            except Exception:  # a malformed packet: counted, the link goes on
                self.stats.bad_packets += 1
                continue
            if msg is None:
                break
            name = msg.get_type()
            if name == "BAD_DATA":
                self.stats.bad_packets += 1
                continue
            self.stats.received[name] = self.stats.received.get(name, 0) + 1
            self._update_state(msg)
            out.append(msg)
            if time.monotonic() > deadline and timeout_s > 0:
                break
        return out

    def _update_state(self, msg: Any) -> None:
        name = msg.get_type()
        s = self.state
        if name == "HEARTBEAT":
            s.heartbeats += 1
            s.armed = bool(msg.base_mode & self._mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            s.custom_mode = int(msg.custom_mode)
        elif name == "ATTITUDE":
            s.attitude = rotation_ned_frd_to_enu_flu(
                Rotation.from_euler("ZYX", [msg.yaw, msg.pitch, msg.roll])
            )
            s.t_boot_ms = int(msg.time_boot_ms)
        elif name == "LOCAL_POSITION_NED":
            s.position_enu = ned_to_enu(np.array([msg.x, msg.y, msg.z]))
            s.velocity_enu = ned_to_enu(np.array([msg.vx, msg.vy, msg.vz]))
        elif name == "ODOMETRY":
            w, x, y, z = msg.q
            R = rotation_ned_frd_to_enu_flu(Rotation.from_quat([x, y, z, w]))
            s.odometry = Pose(R, ned_to_enu(np.array([msg.x, msg.y, msg.z])))

    def close(self) -> None:
        self.conn.close()
