"""The truth a flight's VIO record is judged against: at the times the VIO stamps its states,
which a camera-IMU time offset moves off the frame times."""

from __future__ import annotations

import numpy as np

from quadnav.experiments.vio_flight import VioCameraSensor, world_around
from quadnav.geometry.rotations import Pose
from quadnav.messages import ImageFrame, ImuSample, VehicleState
from quadnav.odometry import KeyframeRecord, OdometryState
from quadnav.rig import rig_named
from quadnav.sim.render import RenderEffects, Renderer

SPEED_M_S = 3.0
PERIOD_NS = 50_000_000  # the euroc rig's camera runs at 20 Hz


class _LateStamps:
    """An odometry that answers each frame with the rig's true pose stamped ``offset_ns`` after
    the frame (as a VIO does that has estimated its camera's time offset), its position the
    vehicle's at that stamp: a perfect estimate of what it claims."""

    cameras = ("cam0",)
    events = ()

    def __init__(self, offset_ns: int, T_V_B: Pose) -> None:
        self.offset_ns, self.T_V_B = offset_ns, T_V_B

    def push(self, sample: ImuSample | ImageFrame) -> OdometryState | None:
        if not isinstance(sample, ImageFrame):
            return None
        t = sample.t_ns + self.offset_ns
        T_W_B = Pose.from_quat_xyzw(np.array([0.0, 0.0, 0.0, 1.0]), _p(t)) @ self.T_V_B
        return OdometryState(
            t_ns=t, T_W_B=T_W_B, v_W_B=np.array([SPEED_M_S, 0.0, 0.0]),
            gyro_bias=np.zeros(3), accel_bias=np.zeros(3),
            cov_pose=np.eye(6) * 1e-4, cov_v=np.eye(3) * 1e-4,
        )  # fmt: skip

    def keyframes(self, *, final: bool = False) -> list[KeyframeRecord]:
        return []

    def timing(self) -> object:
        return _NoTiming()


class _NoTiming:
    def per_call_ms(self) -> dict[str, float]:
        return {}


def _p(t_ns: int) -> np.ndarray:
    return np.array([SPEED_M_S * t_ns * 1e-9, 0.0, 1.0])


def _state(t_ns: int) -> VehicleState:
    return VehicleState(
        t_ns=t_ns, p_W_B=_p(t_ns), v_W_B=np.array([SPEED_M_S, 0.0, 0.0]), a_W_B=np.zeros(3),
        q_W_B_xyzw=np.array([0.0, 0.0, 0.0, 1.0]), w_B=np.zeros(3),
    )  # fmt: skip


def test_states_stamped_off_the_frame_times_are_judged_against_the_truth_then() -> None:
    """Looked up by the exact frame time, every state stamped 1.2 ms after its frame had no
    truth and was left out of the VIO's error: the flight's VIO was judged on its hover."""
    rig = rig_named("euroc")
    vio = _LateStamps(1_200_000, rig.T_V_B)
    scene = world_around(np.array([[0.0, 0.0, 1.0], [4.0, 0.0, 1.0]]), "room", 0)
    sensor = VioCameraSensor(
        rig=rig, vio=vio, renderer=Renderer(scene, rig.cameras[0].camera), imu=None,
        image_rng=np.random.default_rng(0), effects=RenderEffects(read_noise_sigma=0.0),
        first_ns=0,
    )  # fmt: skip
    for k in range(12):
        sensor.sample(_state(k * PERIOD_NS), k * PERIOD_NS, np.random.default_rng(k))
    rec = sensor.record()
    # the last state is stamped after the last frame: no truth to judge it by
    assert np.isfinite(rec.truth_p_W_B[:-1]).all()
    assert np.isnan(rec.truth_p_W_B[-1]).all()
    # the truth at the stamp, not at the frame: the estimate, exact at its stamp, matches it
    err = np.linalg.norm(rec.p_W_B[:-1] - rec.truth_p_W_B[:-1], axis=1)
    assert err.max() < 1e-6
    # (at the frame time it would be 3.6 mm off: the test can tell the two apart)
    assert 1000 * err.max() < SPEED_M_S * 1.2e-3
