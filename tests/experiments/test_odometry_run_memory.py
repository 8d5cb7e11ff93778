"""What the odometry runner keeps as a run goes on (issue 22, item 9: memory of long runs): the
trajectory it writes, one compact row a camera frame, and nothing else that grows."""

from __future__ import annotations

import tracemalloc

import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.experiments.odometry_run import _STATE_BLOCK, _estimate, _States
from quadnav.geometry.rotations import Pose
from quadnav.odometry import OdometryState

T0_NS = 1_700_000_000_000_000_000


def _state(k: int, rng: np.random.Generator) -> OdometryState:
    a = rng.normal(size=(6, 6))
    return OdometryState(
        t_ns=T0_NS + 50_000_000 * k,
        T_W_B=Pose(Rotation.from_rotvec(rng.normal(size=3)), rng.normal(size=3)),
        v_W_B=np.zeros(3), gyro_bias=np.zeros(3), accel_bias=np.zeros(3),
        cov_pose=a @ a.T, cov_v=np.eye(3),
    )  # fmt: skip


def test_a_camera_frame_costs_the_run_under_300_bytes() -> None:
    """36,000 frames (30 minutes at 20 Hz) of a row array each were 474 bytes a frame, 17 MB;
    blocks of rows hold stamp, pose and the covariance's triangle in 232."""
    rng = np.random.default_rng(0)
    states = [_state(k, rng) for k in range(3 * _STATE_BLOCK)]
    for st in states:
        st.T_W_B.R_A_B.as_quat()  # scipy caches on the Rotation: the state's, not the run's
    kept = _States()
    tracemalloc.start()
    try:
        for st in states:
            kept.append(st)
        per_frame = tracemalloc.get_traced_memory()[0] / len(states)
    finally:
        tracemalloc.stop()
    assert per_frame < 300, f"{per_frame:.0f} bytes a frame"


def test_the_written_estimate_is_the_states_in_time_order_the_last_of_a_stamp() -> None:
    rng = np.random.default_rng(1)
    states = [_state(k, rng) for k in range(5000)]  # more than one block
    late = states[4100]
    again = _state(4100, rng)  # the same stamp again (a stereo pair completed late)
    kept = _States()
    for st in [*states, again]:
        kept.append(st)
    assert len(kept) == 5001 and kept.first_t_ns == states[0].t_ns
    est, cov = _estimate(kept)
    assert len(est) == 5000 and np.all(np.diff(est.t_ns) > 0)
    for k, st in ((0, states[0]), (4099, states[4099]), (4100, again), (4999, states[4999])):
        assert est.t_ns[k] == st.t_ns
        np.testing.assert_allclose(est.p_W_B[k], st.T_W_B.p_A_B)
        R = Rotation.from_quat(est.q_W_B_xyzw[k])
        assert (R.inv() * st.T_W_B.R_A_B).magnitude() < 1e-12
        np.testing.assert_allclose(cov[k], st.cov_pose, rtol=1e-12)
    assert not np.allclose(cov[4100], late.cov_pose)
    empty_est, empty_cov = _estimate(_States())
    assert len(empty_est) == 0 and empty_cov.shape == (0, 6, 6)
