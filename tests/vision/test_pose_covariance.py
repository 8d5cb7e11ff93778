"""The analytic Jacobian of the frame chain (PnP pose -> vehicle pose) against central
differences."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from quadnav.geometry.rotations import Pose, so3_log
from quadnav.vision.pose import _chain, chain_jacobian, mount_pose


def _numeric(rt: np.ndarray, TWO: np.ndarray, TCB: np.ndarray, step: float = 1e-6) -> np.ndarray:
    R0 = _chain(rt, TWO, TCB)[:3, :3]
    J = np.zeros((6, 6))
    for k in range(6):
        d = np.zeros(6)
        d[k] = step
        Tp, Tm = _chain(rt + d, TWO, TCB), _chain(rt - d, TWO, TCB)
        J[0:3, k] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * step)
        J[3:6, k] = (so3_log(Tp[:3, :3] @ R0.T) - so3_log(Tm[:3, :3] @ R0.T)) / (2 * step)
    return J


@pytest.mark.parametrize("seed", range(5))
def test_chain_jacobian_matches_central_differences(seed: int) -> None:
    rng = np.random.default_rng(seed)
    # rotation vectors from near zero to near pi (the thesis mount's PnP rotation is ~pi)
    angle = [1e-9, 0.3, 1.5, 2.8, 3.1][seed]
    axis = rng.normal(size=3)
    rvec = angle * axis / np.linalg.norm(axis)
    rt = np.concatenate([rvec, rng.normal(0, 0.5, 3) + [0, 0, 1.5]])
    T_W_O = Pose(Rotation.random(random_state=seed), rng.normal(0, 1, 3))
    T_B_C = mount_pose((180.0, 0.0, 180.0), tuple(rng.normal(0, 0.1, 3)))
    TWO, TCB = T_W_O.matrix(), T_B_C.inverse().matrix()
    np.testing.assert_allclose(chain_jacobian(rt, TWO, TCB), _numeric(rt, TWO, TCB), atol=2e-6)
