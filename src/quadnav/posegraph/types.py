"""The pose graph's inputs and results: its configuration, a loop edge, a problem (the keyframes'
odometry poses and the loops that one optimisation solves: plain arrays, so that it crosses to a
worker process cheaply), the result, and the drift correction published from it.

Frames: ``O`` is an odometry's world (one per odometry ``reset_counter``), ``M`` the map the graph
corrects it into, ``B`` a keyframe's body. A loop edge measures ``T_Bold_Bnew``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import PoseGraphError
from quadnav.geometry.rotations import Pose

__all__ = [
    "DriftCorrection",
    "FourDofFactor",
    "GraphKind",
    "LoopEdge",
    "PoseGraphConfig",
    "PoseGraphProblem",
    "PoseGraphResult",
    "RobustKernel",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

GraphKind = Literal["4dof", "se3", "sim3"]
FourDofFactor = Literal["custom", "native"]
RobustKernel = Literal["huber", "cauchy", "none"]
#: The size of a loop edge's covariance for each graph: (x, y, z, yaw) in the old keyframe's
#: frame; GTSAM's Pose3 order (rx, ry, rz, x, y, z); Similarity3's (rotation, translation, log s).
COV_SIZE: dict[str, int] = {"4dof": 4, "se3": 6, "sim3": 7}


def _positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise PoseGraphError(
            f"PoseGraphConfig.{name} must be a positive finite number, got {value}"
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class PoseGraphConfig:
    """How a pose graph is built and solved.

    Sequential edges join each keyframe to its ``sequential_edges`` predecessors of the same
    odometry frame (VINS-Mono: 4) with the relative pose the odometry gives; the edge to the
    k-th predecessor gets ``sqrt(k)`` times the sigmas (the odometry's drift is a random walk).
    Where the problem carries the odometry's own ``step_var`` (the growth of its position
    variance from one keyframe to the next), a step's position variance is the larger of
    ``sequential_sigma_m`` squared and that growth times the harmonic number of
    ``sequential_edges`` (the overlapping edges count each step's information that many times
    over), and an edge's is the sum over the steps it spans.
    Loop edges get the ``loop_*`` sigmas (or their own covariance) under the ``robust`` kernel
    (``robust_k`` in sigmas of the whitened residual). A 4-DoF graph's ``four_dof_factor``:
    ``custom`` (our factor of VINS-Mono's error) or ``native`` (GTSAM's ``Pose2`` and height
    factors, the same error to first order, 4 to 6 times faster; see :func:`solve`). The first keyframe of each connected
    part of the graph is held fixed. ``max_iterations`` bounds Levenberg-Marquardt (VINS-Mono
    stops Ceres at 5). A published correction that moves the newest keyframe by more than
    ``reset_jump_m`` or turns it by more than ``reset_jump_rad`` raises the output's reset
    counter."""

    kind: GraphKind = "4dof"
    four_dof_factor: FourDofFactor = "native"
    sequential_edges: int = 4
    sequential_sigma_m: float = 0.02
    sequential_sigma_yaw_rad: float = 0.005
    sequential_sigma_rot_rad: float = 0.005  # se3 and sim3: each axis
    sequential_sigma_log_scale: float = 0.01  # sim3
    loop_sigma_m: float = 0.05
    loop_sigma_yaw_rad: float = 0.02
    loop_sigma_rot_rad: float = 0.02  # se3 and sim3
    loop_sigma_log_scale: float = 0.02  # sim3
    robust: RobustKernel = "huber"
    robust_k: float = 3.0
    max_iterations: int = 20
    reset_jump_m: float = 0.1
    reset_jump_rad: float = 0.05

    def __post_init__(self) -> None:
        if self.kind not in COV_SIZE:
            raise PoseGraphError(f"PoseGraphConfig.kind must be one of {sorted(COV_SIZE)}")
        if self.four_dof_factor not in ("custom", "native"):
            raise PoseGraphError("PoseGraphConfig.four_dof_factor must be custom or native")
        if self.robust not in ("huber", "cauchy", "none"):
            raise PoseGraphError("PoseGraphConfig.robust must be huber, cauchy or none")
        if not 1 <= self.sequential_edges <= 100 or not 1 <= self.max_iterations <= 10_000:
            raise PoseGraphError("PoseGraphConfig: sequential_edges 1-100, max_iterations 1-10000")
        for name in (
            "sequential_sigma_m", "sequential_sigma_yaw_rad", "sequential_sigma_rot_rad",
            "sequential_sigma_log_scale", "loop_sigma_m", "loop_sigma_yaw_rad",
            "loop_sigma_rot_rad", "loop_sigma_log_scale", "robust_k", "reset_jump_m",
            "reset_jump_rad",
        ):  # fmt: skip
            _positive(name, float(getattr(self, name)))


def _finite_pose(p: Pose, name: str) -> None:
    if not np.isfinite(p.R_A_B.as_quat()).all():
        raise PoseGraphError(f"{name} has a non-finite rotation")


def _checked_covariance(cov: object, name: str) -> FloatArray:
    """``cov`` as a finite, symmetric, positive-definite square matrix, or a one-line error."""
    c = np.asarray(cov, dtype=np.float64)
    if c.ndim != 2 or c.shape[0] != c.shape[1] or not np.isfinite(c).all():
        raise PoseGraphError(f"{name} must be a finite square matrix, got shape {c.shape}")
    if not np.allclose(c, c.T, rtol=1e-9, atol=1e-12):
        raise PoseGraphError(f"{name} is not symmetric")
    try:
        np.linalg.cholesky(c)
    except np.linalg.LinAlgError:
        raise PoseGraphError(f"{name} is not positive definite") from None
    return c


@dataclass(frozen=True, slots=True, kw_only=True)
class LoopEdge:
    """A loop: the pose of keyframe ``new`` in keyframe ``old``'s body frame, ``T_old_new``, as
    the geometric verification measured it; ``scale`` its scale ratio (a Sim(3) graph's,
    otherwise 1); ``cov`` its covariance (the graph's size, see :data:`COV_SIZE`; None: the
    configuration's loop sigmas)."""

    old: int
    new: int
    T_old_new: Pose
    scale: float = 1.0
    cov: FloatArray | None = None

    def __post_init__(self) -> None:
        if self.old == self.new:
            raise PoseGraphError(f"LoopEdge joins keyframe {self.old} to itself")
        _finite_pose(self.T_old_new, "LoopEdge.T_old_new")
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise PoseGraphError(f"LoopEdge.scale must be positive and finite, got {self.scale}")
        if self.cov is not None:
            object.__setattr__(self, "cov", _checked_covariance(self.cov, "LoopEdge.cov"))


@dataclass(frozen=True, slots=True, kw_only=True)
class PoseGraphProblem:
    """What one optimisation solves: keyframe ``indices`` (increasing), the odometry frame of
    each (``reset_counters``), their odometry poses ``T_O_B`` as ``positions`` (N, 3) and
    ``quats_xyzw`` (N, 4), the ``loops`` and the configuration; ``fixed`` (N,) the keyframes
    held where they are (a map loaded from disk, as VINS-Mono holds its previous pose graph;
    None: only the first of each connected part); ``step_var`` (N,) the growth of the
    odometry's position variance (m^2 an axis) from the keyframe before (None: the config's
    sigmas alone; see :class:`PoseGraphConfig`). Build it with :meth:`from_poses`, which
    refuses bad input with a one-line :class:`PoseGraphError`."""

    indices: IntArray
    reset_counters: IntArray
    positions: FloatArray
    quats_xyzw: FloatArray
    loops: tuple[LoopEdge, ...] = ()
    config: PoseGraphConfig = field(default_factory=PoseGraphConfig)
    fixed: NDArray[np.bool_] | None = None
    step_var: FloatArray | None = None

    @classmethod
    def from_poses(
        cls,
        indices: Sequence[int],
        poses: Sequence[Pose],
        loops: Sequence[LoopEdge] = (),
        *,
        reset_counters: Sequence[int] | IntArray | None = None,
        config: PoseGraphConfig | None = None,
        fixed: Sequence[bool] | None = None,
        step_var: Sequence[float] | FloatArray | None = None,
    ) -> PoseGraphProblem:
        """The problem of keyframes ``indices`` at odometry poses ``poses`` with ``loops``."""
        idx = np.asarray(indices, dtype=np.int64)
        if idx.ndim != 1 or len(idx) != len(poses) or len(idx) == 0:
            raise PoseGraphError(
                f"{len(idx)} indices for {len(poses)} poses: one each, at least one"
            )
        if np.any(np.diff(idx) <= 0):
            raise PoseGraphError("keyframe indices must be strictly increasing")
        for k, p in zip(idx.tolist(), poses, strict=True):
            _finite_pose(p, f"the pose of keyframe {k}")
        rc = (
            np.zeros(len(idx), np.int64)
            if reset_counters is None
            else np.asarray(reset_counters, np.int64)
        )
        if rc.shape != idx.shape:
            raise PoseGraphError("reset_counters needs one value per keyframe")
        held = None if fixed is None else np.asarray(fixed, dtype=bool)
        if held is not None and held.shape != idx.shape:
            raise PoseGraphError("fixed needs one value per keyframe")
        steps = None if step_var is None else np.asarray(step_var, dtype=np.float64)
        if steps is not None and (
            steps.shape != idx.shape or not np.all(np.isfinite(steps)) or np.any(steps < 0)
        ):
            raise PoseGraphError("step_var needs one finite, non-negative value per keyframe")
        known = set(idx.tolist())
        for e in loops:
            if e.old not in known or e.new not in known:
                raise PoseGraphError(f"loop edge {e.old} -> {e.new} names an unknown keyframe")
        return cls(
            indices=idx,
            reset_counters=rc,
            positions=np.array([p.p_A_B for p in poses], dtype=np.float64),
            quats_xyzw=np.array([p.R_A_B.as_quat() for p in poses], dtype=np.float64),
            loops=tuple(loops),
            config=config or PoseGraphConfig(),
            fixed=held,
            step_var=steps,
        )

    def poses(self) -> tuple[Pose, ...]:
        """The odometry poses ``T_O_B``."""
        return tuple(
            Pose.from_quat_xyzw(q, p) for q, p in zip(self.quats_xyzw, self.positions, strict=True)
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class PoseGraphResult:
    """An optimised graph: keyframe ``indices`` and their corrected poses ``T_M_B`` (``scales``:
    a Sim(3) graph's, else None); ``loop_chi``: each loop edge's whitened residual norm after
    optimisation, before the robust kernel (a false loop keeps a large one); the total error
    before and after, the iterations and the wall time of the solve."""

    kind: GraphKind
    indices: IntArray
    poses: tuple[Pose, ...]
    scales: FloatArray | None
    loop_chi: FloatArray
    initial_error: float
    final_error: float
    iterations: int
    solve_s: float

    def positions(self) -> FloatArray:
        """The corrected positions (N, 3)."""
        return np.array([p.p_A_B for p in self.poses], dtype=np.float64).reshape(-1, 3)


@dataclass(frozen=True, slots=True, kw_only=True)
class DriftCorrection:
    """The map-to-odometry transform ``T_M_O`` of odometry frame ``odometry_reset_counter``,
    from the optimisation that ended with keyframe ``keyframe_index`` (time ``t_ns``; -1 and 0
    before any); ``reset_counter`` counts the corrections that jumped (a corrected output adds it
    to the odometry's own counter); ``jump_m`` and ``jump_rad`` are this correction's move of the
    newest keyframe against the previous correction; ``result`` the optimised graph."""

    t_ns: int = 0
    keyframe_index: int = -1
    odometry_reset_counter: int = 0
    T_M_O: Pose = field(default_factory=Pose.identity)
    reset_counter: int = 0
    jump_m: float = 0.0
    jump_rad: float = 0.0
    result: PoseGraphResult | None = None
