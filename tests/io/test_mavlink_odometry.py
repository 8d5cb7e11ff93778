"""A VIO's odometry to PX4 as a companion computer sends it: ODOMETRY over loopback, decoded by a
listener, pose, velocity, covariances, reset counter, quality and estimator type round trip."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.geometry.frames import enu_to_ned, rotation_enu_flu_to_ned_frd
from quadnav.io.mavlink import MavlinkLink, decode_odometry, from_upper_triangle
from quadnav.messages import OdometrySample
from tests.loopback import free_port
from tests.loopback import no_remote_bind as no_remote_bind_fixture

no_remote_bind = no_remote_bind_fixture


def _sample(rng: np.random.Generator, k: int) -> OdometrySample:
    A = rng.normal(size=(6, 6)) * np.array([0.03] * 3 + [0.01] * 3)
    B = rng.normal(size=(3, 3)) * 0.02
    return OdometrySample(
        t_ns=2_000_000_000 + k * 50_000_000,
        p_W_B=rng.uniform(-5, 5, 3),
        q_W_B_xyzw=Rotation.from_euler("ZYX", rng.uniform([-3, -0.4, -0.4], [3, 0.4, 0.4])).as_quat(),
        v_W_B=rng.uniform(-2, 2, 3),
        cov_pose=A @ A.T + np.eye(6) * 1e-6,
        cov_v=B @ B.T + np.eye(3) * 1e-6,
        reset_counter=k // 20,
        quality=int(rng.integers(1, 101)),
    )  # fmt: skip


def test_vio_odometry_round_trips_over_loopback(no_remote_bind: list[object]) -> None:
    port = free_port()
    px4 = MavlinkLink(f"udpin:127.0.0.1:{port}", system=1, component=1)
    companion = MavlinkLink(f"udpout:127.0.0.1:{port}", system=1, component=197)
    rng = np.random.default_rng(4)
    sent = [_sample(rng, k) for k in range(60)]
    got = []
    companion.heartbeat()
    for odo in sent:
        companion.send_odometry_sample(odo)
        got += [m for m in px4.poll() if m.get_type() == "ODOMETRY"]
        time.sleep(0.002)
    deadline = time.monotonic() + 2.0
    while len(got) < len(sent) and time.monotonic() < deadline:
        got += [m for m in px4.poll(timeout_s=0.2) if m.get_type() == "ODOMETRY"]
    assert len(got) == len(sent)
    assert px4.state.heartbeats == 1
    m = px4._mavutil.mavlink
    for msg, odo in zip(got, sent, strict=True):
        # what PX4 reads: NED position, FRD attitude, body-frame velocity, the frames and type
        assert (msg.frame_id, msg.child_frame_id) == (m.MAV_FRAME_LOCAL_FRD, m.MAV_FRAME_BODY_FRD)
        assert msg.estimator_type == m.MAV_ESTIMATOR_TYPE_VIO
        assert (msg.reset_counter, msg.quality) == (odo.reset_counter, odo.quality)
        np.testing.assert_allclose([msg.x, msg.y, msg.z], enu_to_ned(odo.p_W_B), atol=1e-5)
        R_frd = rotation_enu_flu_to_ned_frd(Rotation.from_quat(odo.q_W_B_xyzw))
        w, x, y, z = msg.q
        assert (Rotation.from_quat([x, y, z, w]).inv() * R_frd).magnitude() < 1e-5
        v_ned = R_frd.apply([msg.vx, msg.vy, msg.vz])
        np.testing.assert_allclose(v_ned, enu_to_ned(odo.v_W_B), atol=1e-5)
        # the velocity covariance's speed block is the world one in the body's FRD axes
        C_frd = from_upper_triangle(list(msg.velocity_covariance))[0:3, 0:3]
        A = R_frd.as_matrix().T @ np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
        np.testing.assert_allclose(C_frd, A @ odo.cov_v @ A.T, rtol=1e-5, atol=1e-11)
        # and everything back in quadnav's frames (float32 on the wire)
        back = decode_odometry(msg)
        assert back.t_ns == odo.t_ns and back.reset_counter == odo.reset_counter
        np.testing.assert_allclose(back.p_W_B, odo.p_W_B, atol=1e-5)
        np.testing.assert_allclose(back.v_W_B, odo.v_W_B, atol=1e-5)
        dq = Rotation.from_quat(back.q_W_B_xyzw).inv() * Rotation.from_quat(odo.q_W_B_xyzw)
        assert dq.magnitude() < 1e-5
        np.testing.assert_allclose(back.cov_pose, odo.cov_pose, rtol=1e-4, atol=1e-9)
        np.testing.assert_allclose(back.cov_v, odo.cov_v, rtol=1e-4, atol=1e-10)
    assert companion.stats.sent == {"HEARTBEAT": 1, "ODOMETRY": len(sent)}
    assert all(a[0] == "127.0.0.1" for a in no_remote_bind if isinstance(a, tuple))
    px4.close()
    companion.close()


def test_quadnav_run_mavlink_sends_the_flight_s_odometry(
    tmp_path: Path, no_remote_bind: list[object]
) -> None:
    """``quadnav run indoor_vio_odometry --mavlink``: a listener (the autopilot) gets a heartbeat
    a second and every odometry sample of the flight, as the VIO's, in the vehicle's FRD."""
    port = free_port()
    px4 = MavlinkLink(f"udpin:127.0.0.1:{port}", system=1, component=1)
    args = ["run", "indoor_vio_odometry", "--mavlink", f"udpout:127.0.0.1:{port}",
            "--out", str(tmp_path), "--set", "plan.takeoff_s=1", "--set", "plan.duration_s=2"]  # fmt: skip
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    msgs = px4.poll(timeout_s=1.0)
    odo = [m for m in msgs if m.get_type() == "ODOMETRY"]
    # 3.5 s of 20 Hz odometry, the last 50 ms (its latency) not yet delivered
    assert 65 <= len(odo) <= 70
    assert px4.state.heartbeats >= 3
    m = px4._mavutil.mavlink
    assert {x.estimator_type for x in odo} == {m.MAV_ESTIMATOR_TYPE_VIO}
    assert all(abs(x.z) < 0.2 for x in odo[:10])  # on the ground, NED z = -height
    assert f"{len(odo)} ODOMETRY" in result.output.replace("\n", " ")
    px4.close()


def test_mavlink_needs_a_scenario_with_a_vio(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app,
        ["run", "indoor_vision_pose", "--mavlink", "udpout:127.0.0.1:9", "--out", str(tmp_path)],
    )
    assert result.exit_code == 2
    assert "--mavlink sends the VIO's odometry" in result.stderr
    assert "Traceback" not in result.output
