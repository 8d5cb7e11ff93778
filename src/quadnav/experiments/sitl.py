"""A software-in-the-loop vehicle that speaks MAVLink: the rigid body with its IMU, barometer
and onboard pose sensor, the navigation EKF, and the cascaded PID, run in real time. It sends
HEARTBEAT (1 Hz), ATTITUDE (50 Hz), LOCAL_POSITION_NED and ODOMETRY (30 Hz); it takes
arm/disarm (MAV_CMD_COMPONENT_ARM_DISARM), PX4's offboard mode (MAV_CMD_DO_SET_MODE or
SET_MODE with main mode 6), SET_POSITION_TARGET_LOCAL_NED setpoints, and fuses the
VISION_POSITION_ESTIMATEs a companion sends it. As PX4, it leaves offboard for a position hold
when setpoints stop for 0.5 s.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.control.base import Setpoint
from quadnav.control.cascaded_pid import CascadedPid
from quadnav.errors import ExperimentError
from quadnav.estimation.horizon import HorizonConfig
from quadnav.estimation.nav_ekf import NavEkf, NavEkfConfig
from quadnav.estimation.nav_filter import InitialSigmas, NavFilterSetup, build_nav_filter
from quadnav.geometry.frames import (
    enu_to_ned,
    ned_to_enu,
    rotation_enu_flu_to_ned_frd,
    rotation_ned_frd_to_enu_flu,
)
from quadnav.geometry.rotations import Pose, rotation_matrix_xyzw
from quadnav.io.mavlink import MavlinkLink, decode_vehicle_command
from quadnav.messages import HeightSample, PoseSample
from quadnav.sim.rigid_body import RigidBodyQuadrotor
from quadnav.sim.sensors import BaroSensor, DelayLine, IntegratingImu, VisionPoseSensor
from quadnav.units import s_to_ns
from quadnav.vehicle import RigidBodyParams

__all__ = ["PX4_OFFBOARD", "SitlVehicle"]

FloatArray = NDArray[np.float64]
PX4_OFFBOARD = 6 << 16  # PX4 custom mode: main mode OFFBOARD
SETPOINT_TIMEOUT_S = 0.5


@dataclass
class SitlVehicle:
    """Run with :meth:`run` (blocking) or :meth:`start` (a thread); :attr:`truth_log` keeps the
    true positions for tests."""

    url: str = "udpin:127.0.0.1:14540"
    signing_key: bytes | None = None
    allow_remote: bool = False  # bind a non-loopback address (anyone there may command it)
    sim_dt_s: float = 0.002
    seed: int = 0
    truth_log: list[tuple[float, FloatArray]] = field(default_factory=list)

    def __post_init__(self) -> None:
        rng = np.random.default_rng(self.seed)
        self.rng = rng
        self.params = RigidBodyParams()
        self.sim = RigidBodyQuadrotor(self.params, dt_s=self.sim_dt_s)
        self.ctrl = CascadedPid(self.params, dt_s=self.sim_dt_s)
        self.imu = IntegratingImu(
            period_ns=4_000_000,
            gyro_sigma_rad_s=0.005,
            accel_sigma_m_s2=0.05,
            gravity_m_s2=self.params.gravity_m_s2,
        )
        self.baro = BaroSensor(period_ns=20_000_000, sigma_m=0.1)
        self.vision = VisionPoseSensor(period_ns=33_333_333, sigma_m=0.01, yaw_sigma_rad=0.01)
        self.vision_line: DelayLine[PoseSample] = DelayLine(delay_ns=100_000_000)
        horizon = HorizonConfig(
            imu_period_ns=4_000_000,
            max_delay_ns=100_000_000,
            tau_vel_s=0.1,
            tau_pos_s=0.1,
            max_fusion_log=10_000,
        )
        # It boots standing at the origin, level and facing east: a tight initial state.
        sigmas = InitialSigmas(
            tilt_rad=0.01,
            yaw_rad=0.01,
            vel_m_s=0.01,
            pos_xy_m=0.01,
            pos_z_m=0.01,
            gyro_bias_rad_s=1e-3,
            accel_bias_m_s2=1e-3,
        )
        setup = NavFilterSetup(ekf=NavEkfConfig(), horizon=horizon, sigmas=sigmas)
        self.est = build_nav_filter(
            setup, t0_ns=0, p0=np.zeros(3), q0_xyzw=np.array([0, 0, 0, 1.0])
        )
        assert isinstance(self.est.filter, NavEkf)
        self.ekf = self.est.filter
        self.link = MavlinkLink(
            self.url,
            system=1,
            component=1,
            signing_key=self.signing_key,
            allow_remote=self.allow_remote,
        )
        self.armed = False
        self.offboard = False
        self.setpoint: tuple[FloatArray, float] | None = None
        self.t_setpoint = -1.0
        self.hold: tuple[FloatArray, float] | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.last_gyro = np.zeros(3)
        self.vision_received = 0

    # -- MAVLink in --------------------------------------------------------------------------
    def _handle(self, msg: Any, t_s: float) -> None:
        command = decode_vehicle_command(msg)
        name = msg.get_type()
        if command is not None:
            if command.kind == "arm":
                self.armed = command.arm
                if not self.armed:
                    self.offboard = False
            elif command.kind == "set_mode":
                self._set_mode(command.custom_mode, t_s)
            self.link.ack_command(command)
        elif name == "SET_POSITION_TARGET_LOCAL_NED":
            p = ned_to_enu(np.array([msg.x, msg.y, msg.z]))
            if np.isfinite(p).all() and math.isfinite(msg.yaw):
                self.setpoint = (p, math.pi / 2 - msg.yaw)
                self.t_setpoint = t_s
        elif name == "VISION_POSITION_ESTIMATE":
            R = rotation_ned_frd_to_enu_flu(
                Rotation.from_euler("ZYX", [msg.yaw, msg.pitch, msg.roll])
            )
            p = ned_to_enu(np.array([msg.x, msg.y, msg.z]))
            var = (
                float(msg.covariance[0])
                if len(msg.covariance)
                and math.isfinite(msg.covariance[0])
                and msg.covariance[0] > 0
                else 1e-4
            )
            try:
                self.est.push(
                    PoseSample(
                        t_ns=int(msg.usec) * 1000,
                        p_W_B=p,
                        q_W_B_xyzw=R.as_quat(),
                        sigma_pos_m=math.sqrt(var),
                        sigma_yaw_rad=0.05,
                        reset_counter=int(msg.reset_counter),
                        source="mavlink_vision",
                    )
                )
                self.vision_received += 1
            except Exception:  # a garbage estimate is counted by the link, not flown on
                self.link.stats.bad_packets += 1

    def _set_mode(self, custom_mode: int, t_s: float) -> None:
        # PX4 enters offboard only with a setpoint stream already flowing
        self.offboard = (
            custom_mode & 0xFF0000
        ) == PX4_OFFBOARD and t_s - self.t_setpoint < SETPOINT_TIMEOUT_S

    # -- the loop ----------------------------------------------------------------------------
    def step(self) -> None:
        truth = self.sim.state()
        t_ns = truth.t_ns
        t_s = t_ns * 1e-9
        pose = self.vision.sample(truth, t_ns, self.rng)
        if pose is not None:
            self.vision_line.push(pose)
        h = self.baro.sample(truth, t_ns, self.rng)
        for _, arrived in self.vision_line.pop_arrived(t_ns):
            self.est.push(arrived)
        if h is not None:
            self.est.push(HeightSample(t_ns=t_ns, z_m=h.z_m, sigma_m=h.sigma_m))
        imu = self.imu.accumulate(truth, self.sim_dt_s, self.rng) if t_ns > 0 else None
        if imu is not None:
            self.est.push(imu)
            self.last_gyro = imu.gyro_rad_s
        state = self.est.output()
        pos = state.p_W_B
        R_now = rotation_matrix_xyzw(state.q_W_B_xyzw)
        yaw_now = math.atan2(R_now[1, 0], R_now[0, 0])
        if self.offboard and t_s - self.t_setpoint > SETPOINT_TIMEOUT_S:
            self.offboard = False  # setpoints stopped: hold where we are, facing where we face
            self.hold = (pos.copy(), yaw_now)
        if not self.armed:
            cmd = np.zeros(4)
        else:
            target = (
                self.setpoint
                if self.offboard and self.setpoint is not None
                else (self.hold or (pos.copy(), 0.0))
            )
            if self.hold is None and not self.offboard:
                self.hold = (np.array([pos[0], pos[1], max(pos[2], 0.0)]), 0.0)
            cmd = self.ctrl(
                t_ns, state, Setpoint(p=target[0], v=np.zeros(3), a=np.zeros(3), yaw_rad=target[1])
            ).rotors()
        if self.offboard:
            self.hold = None
        self.sim.step(cmd)
        if int(t_ns // 2_000_000) % 10 == 0:
            self.truth_log.append((t_s, truth.p_W_B.copy()))

    def _telemetry(self, k: int, t_s: float) -> None:
        o = self.est.output()
        R = Rotation.from_quat(o.q_W_B_xyzw)
        if k % 500 == 0:
            self.link.heartbeat(
                vehicle=True,
                armed=self.armed,
                custom_mode=PX4_OFFBOARD if self.offboard else 3 << 16,
            )
        if k % 10 == 0:
            rpy = rotation_enu_flu_to_ned_frd(R).as_euler("ZYX")[::-1]
            w = self.last_gyro * np.array([1.0, -1.0, -1.0])
            self.link.mav.attitude_send(int(t_s * 1e3), *map(float, rpy), *map(float, w))
            self.link._count("ATTITUDE")
        if k % 16 == 0:
            p, v = enu_to_ned(o.p_W_B), enu_to_ned(o.v_W_B)
            self.link.mav.local_position_ned_send(int(t_s * 1e3), *map(float, p), *map(float, v))
            self.link._count("LOCAL_POSITION_NED")
            self.link.send_odometry(s_to_ns(t_s), Pose(R, o.p_W_B), np.eye(6) * 1e-4, o.v_W_B)

    def run(self, duration_s: float | None = None) -> None:
        """Real time: one simulator step per ``sim_dt_s`` of wall time; MAVLink every step."""
        if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
            raise ExperimentError(f"SITL duration_s must be finite and positive, got {duration_s}")
        t_wall0 = time.monotonic()
        k = 0
        while not self._stop.is_set():
            t_s = k * self.sim_dt_s
            if duration_s is not None and t_s >= duration_s:
                break
            for msg in self.link.poll():
                self._handle(msg, t_s)
            self.step()
            self._telemetry(k, t_s)
            k += 1
            lag = t_wall0 + k * self.sim_dt_s - time.monotonic()
            if lag > 0:
                time.sleep(lag)

    def start(self) -> None:
        self._thread = threading.Thread(target=self.run, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self.link.close()
