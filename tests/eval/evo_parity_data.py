"""The perturbed estimate the evo-parity tests compare against evo 1.38.1's numbers."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.geometry import Trajectory


def perturbed_copy(ref: Trajectory, *, seed: int = 12) -> Trajectory:
    """``ref`` with a random-walk drift, white noise and attitude drift, and a frozen stretch
    (poses 3000-3199 repeat pose 3000, so path distances tie). Seeded: the same file for a given
    numpy (evo's numbers in test_evo_parity.py were computed on the copy numpy 2.4.6 makes)."""
    rng = np.random.default_rng(seed)
    n = len(ref)
    p = ref.p_W_B + np.cumsum(rng.normal(0, 0.002, (n, 3)), axis=0) + rng.normal(0, 0.01, (n, 3))
    dR = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.0005, (n, 3)), axis=0))
    q = (ref.R_W_B * dR).as_quat()
    if n > 3200:
        p[3000:3200] = p[3000]
        q[3000:3200] = q[3000]
    return Trajectory(t_ns=ref.t_ns, p_W_B=p, q_W_B_xyzw=q, name="perturbed")
