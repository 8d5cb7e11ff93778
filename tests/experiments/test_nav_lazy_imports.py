"""Issue 21, item 11: a flight that renders no image and runs no VIO loads neither OpenCV nor
GTSAM (importing the navigation experiment cost 1.0 s when ``quadnav.vio`` and the renderers
were imported eagerly). Each check runs in a fresh interpreter, whose ``sys.modules`` is its own."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import quadnav
from quadnav.jit import JIT_ENABLED

SRC = Path(quadnav.__file__).resolve().parents[1]  # (the copy of the package under test)
HEAVY = ("cv2", "gtsam")

FLY_POSE = """
import sys
from quadnav.experiments.nav import run_nav
from quadnav.experiments.scenarios import nav_builtin
sc = nav_builtin({name!r}, {overrides!r})
r = run_nav(sc, 0)
assert len(r.t_ns) > 100, len(r.t_ns)
print(" ".join(m for m in {heavy!r} if m in sys.modules))
"""


def _loaded(code: str) -> list[str]:
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600
    )
    assert out.returncode == 0, out.stderr
    return out.stdout.split()


def test_importing_the_navigation_experiment_loads_neither_opencv_nor_gtsam() -> None:
    code = f"import sys, quadnav.experiments.nav, quadnav.experiments.nav_study, quadnav.vio\n" \
        f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))"  # fmt: skip
    assert _loaded(code) == []


@pytest.mark.parametrize(
    ("name", "overrides"),
    [
        ("indoor_vision_pose", ["plan.square_m=0.5", "plan.hold_s=0.5", "vision.dropouts_s=[]"]),
        ("indoor_vio_odometry", ["plan.height_m=1", "plan.forward_m=1", "plan.duration_s=3"]),
    ],
)
def test_a_flight_without_images_or_vio_loads_neither(name: str, overrides: list[str]) -> None:
    assert _loaded(FLY_POSE.format(name=name, overrides=overrides, heavy=HEAVY)) == []


def test_the_vio_s_settings_validate_without_either() -> None:
    """The scenario's vio section is VioConfig's fields: validating it imports no tracker."""
    code = FLY_POSE.replace("r = run_nav(sc, 0)\nassert len(r.t_ns) > 100, len(r.t_ns)\n", "")
    assert _loaded(code.format(name="indoor_vio", overrides=["vio.window_keyframes=12"],
                               heavy=HEAVY)) == []  # fmt: skip


def test_importing_the_navigation_experiment_does_not_load_scipy_stats() -> None:
    """scipy.stats was 0.6 s of the import, for three chi-square quantiles
    (``quadnav.estimation.chi2`` has them from scipy.special)."""
    code = "import sys, quadnav.experiments.nav\nprint('scipy.stats' in sys.modules)"
    assert _loaded(code) == ["False"]


KERNELS_CALLED = """
import sys
import numpy as np
import quadnav.estimation.horizon, quadnav.estimation.nav_ekf, quadnav.sim.rigid_body
from quadnav.geometry.rotations import so3_log
before = "numba" in sys.modules
from quadnav.estimation.nav_ekf import NavKinematics
p, v, R = NavKinematics().integrate(
    np.zeros(3), np.zeros(3), np.eye(3).ravel(), np.array([0.0, 0.0, 0.1]), np.zeros(3), 1.0
)
print(before, "numba" in sys.modules, round(float(so3_log(R.reshape(3, 3))[2]), 12))
"""


@pytest.mark.skipif(not JIT_ENABLED, reason="QUADNAV_JIT=0 in the environment: numba never loads")
def test_numba_loads_at_a_kernels_first_call_not_at_import() -> None:
    """Importing the modules that define compiled kernels costs no numba (half a second of
    start-up for commands that never run one); the first call loads it, and a kernel that
    calls another module's kernel (the output predictor's step calls the rotations') runs."""
    assert _loaded(KERNELS_CALLED) == ["False", "True", "0.1"]
