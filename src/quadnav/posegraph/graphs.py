"""Building and solving a pose graph in GTSAM: the 4-DoF graph of VINS-Mono (our factor on
``Vector4`` variables), the SE(3) graph (``BetweenFactorPose3``) and the Sim(3) graph
(``BetweenFactorSimilarity3``), with the same edges: sequential ones to the previous keyframes
of the same odometry frame, loop ones under a robust kernel, the first keyframe of each
connected part held (a prior of a micrometre, a microradian).

:func:`solve` is a plain function of a picklable :class:`PoseGraphProblem`, so that it runs in a
worker process as well as in the caller's (GTSAM's ``optimize`` holds the GIL).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

from quadnav.errors import PoseGraphError
from quadnav.geometry.gtsam_bridge import pose3, to_pose
from quadnav.geometry.rotations import Pose, rot_z, yaw_of
from quadnav.posegraph.fourdof import FourDofMeasurement, four_dof_factor, split_yaw
from quadnav.posegraph.types import (
    COV_SIZE,
    FloatArray,
    LoopEdge,
    PoseGraphConfig,
    PoseGraphProblem,
    PoseGraphResult,
)

__all__ = [
    "anchors", "build_graph", "levenberg_marquardt", "sequential_covariances", "sequential_pairs",
    "solve",
]  # fmt: skip

_FIXED_SIGMA = 1e-6  # the prior that holds an anchor keyframe


def sequential_pairs(problem: PoseGraphProblem) -> list[tuple[int, int, int]]:
    """The sequential edges ``(i, j, k)`` (positions in the problem, ``j = i + k``): each
    keyframe to its ``sequential_edges`` predecessors in the same odometry frame (none between
    two held keyframes)."""
    rc = problem.reset_counters
    held = problem.fixed if problem.fixed is not None else np.zeros(len(rc), bool)
    out = []
    for j in range(len(rc)):
        for k in range(1, problem.config.sequential_edges + 1):
            if j - k >= 0 and rc[j - k] == rc[j] and not (held[j] and held[j - k]):
                out.append((j - k, j, k))
    return out


def sequential_covariances(
    problem: PoseGraphProblem,
) -> list[tuple[int, int, int, FloatArray]]:
    """Each sequential edge ``(i, j, k)`` with its covariance: ``k`` times the config's
    sigmas squared; with the problem's ``step_var``, the position's variance is the sum over
    the steps the edge spans of the larger of ``sequential_sigma_m`` squared and the step's
    variance growth times the harmonic number of ``sequential_edges``
    (:class:`PoseGraphConfig`)."""
    config = problem.config
    var = _sigmas(config, loop=False) ** 2
    pos = slice(0, 3) if config.kind == "4dof" else slice(3, 6)
    out = []
    if problem.step_var is None:
        steps = None
    else:
        h = sum(1.0 / n for n in range(1, config.sequential_edges + 1))
        steps = np.concatenate(
            [[0.0], np.cumsum(np.maximum(problem.step_var * h, config.sequential_sigma_m**2))]
        )
    for i, j, k in sequential_pairs(problem):
        v = var * k
        if steps is not None:
            v = v.copy()
            v[pos] = steps[j + 1] - steps[i + 1]
        out.append((i, j, k, np.diag(v)))
    return out


def anchors(problem: PoseGraphProblem) -> list[int]:
    """The first keyframe (position) of each connected part of the graph: the ones held."""
    parent = list(range(len(problem.indices)))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    pos = {int(k): n for n, k in enumerate(problem.indices)}
    pairs = [(i, j) for i, j, _ in sequential_pairs(problem)]
    pairs += [(pos[e.old], pos[e.new]) for e in problem.loops]
    for a, b in pairs:
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)  # the root of a part is its first keyframe
    return sorted({root(n) for n in range(len(parent))})


def _noise(cov: FloatArray) -> gtsam.noiseModel.Base:
    """A Gaussian noise model of ``cov``: diagonal when it is."""
    if np.count_nonzero(cov - np.diag(np.diag(cov))) == 0:
        return gtsam.noiseModel.Diagonal.Sigmas(np.sqrt(np.diag(cov)))
    return gtsam.noiseModel.Gaussian.Covariance(cov)


def _robust(config: PoseGraphConfig, base: gtsam.noiseModel.Base) -> gtsam.noiseModel.Base:
    if config.robust == "none":
        return base
    est = gtsam.noiseModel.mEstimator
    kernel = (est.Huber if config.robust == "huber" else est.Cauchy).Create(config.robust_k)
    return gtsam.noiseModel.Robust.Create(kernel, base)


def _loop_cov(config: PoseGraphConfig, e: LoopEdge) -> FloatArray:
    """A loop edge's covariance (its own, or the configuration's sigmas)."""
    n = COV_SIZE[config.kind]
    if e.cov is None:
        return np.diag(_sigmas(config, loop=True) ** 2)
    if e.cov.shape != (n, n):
        raise PoseGraphError(
            f"loop edge {e.old} -> {e.new}: a {config.kind} graph needs a {n}x{n} covariance"
        )
    return e.cov


def _sigmas(config: PoseGraphConfig, *, loop: bool) -> FloatArray:
    m = config.loop_sigma_m if loop else config.sequential_sigma_m
    if config.kind == "4dof":
        yaw = config.loop_sigma_yaw_rad if loop else config.sequential_sigma_yaw_rad
        return np.array([m, m, m, yaw])
    r = config.loop_sigma_rot_rad if loop else config.sequential_sigma_rot_rad
    s = config.loop_sigma_log_scale if loop else config.sequential_sigma_log_scale
    return np.array([r, r, r, m, m, m] + ([s] if config.kind == "sim3" else []))


# ----------------------------------------------------------------------------- one builder per kind
# Each puts the variables' initial values in ``values`` and returns the factors of an edge
# (i, j, measured T_i_j, scale, covariance, robust or not) and of the prior that holds a keyframe.
# Positions in the problem are the keys (the native 4-DoF graph's heights: keys N + n).

_Edge = Callable[[int, int, gtsam.Pose3, float, FloatArray, bool], list[gtsam.NonlinearFactor]]
_Fixed = Callable[[int], list[gtsam.NonlinearFactor]]


def _fixed_noise(dim: int) -> gtsam.noiseModel.Base:
    return gtsam.noiseModel.Isotropic.Sigma(dim, _FIXED_SIGMA)


def _four_dof_measurement(
    R: FloatArray, tilts: list[FloatArray], i: int, T_i_j: gtsam.Pose3
) -> FourDofMeasurement:
    """The 4-DoF measurement of relative pose ``T_i_j`` from keyframe i at odometry attitude ``R[i]``."""
    dyaw = yaw_of(R[i] @ T_i_j.rotation().matrix()) - yaw_of(R[i])
    return FourDofMeasurement(
        t_ij=np.asarray(T_i_j.translation()), R_tilt_i=tilts[i],
        dyaw_rad=math.remainder(dyaw, 2 * math.pi),
    )  # fmt: skip


def _four_dof(
    config: PoseGraphConfig, R: FloatArray, p: FloatArray, values: gtsam.Values
) -> tuple[_Edge, _Fixed, list[FloatArray]]:
    """Our factor (``CustomFactor``) on ``Vector4`` (x, y, z, yaw) variables."""
    tilts = []
    for n in range(len(p)):
        yaw, tilt = split_yaw(R[n])
        tilts.append(tilt)
        values.insert(n, np.array([*p[n], yaw]))

    def edge(
        i: int, j: int, T_i_j: gtsam.Pose3, _s: float, cov: FloatArray, robust: bool
    ) -> list[gtsam.NonlinearFactor]:
        noise = _robust(config, _noise(cov)) if robust else _noise(cov)
        return [four_dof_factor(i, j, _four_dof_measurement(R, tilts, i, T_i_j), noise)]

    def fixed(n: int) -> list[gtsam.NonlinearFactor]:
        return [gtsam.PriorFactorVector(n, values.atVector(n), _fixed_noise(4))]

    return edge, fixed, tilts


def _four_dof_native(
    config: PoseGraphConfig, R: FloatArray, p: FloatArray, values: gtsam.Values
) -> tuple[_Edge, _Fixed, list[FloatArray]]:
    """GTSAM's own factors: ``Pose2`` (x, y, yaw) and a height; see :func:`solve`."""
    N, tilts = len(p), []
    for n in range(N):
        yaw, tilt = split_yaw(R[n])
        tilts.append(tilt)
        values.insert(n, gtsam.Pose2(p[n, 0], p[n, 1], yaw))
        values.insert(N + n, float(p[n, 2]))

    def edge(
        i: int, j: int, T_i_j: gtsam.Pose3, _s: float, cov: FloatArray, robust: bool
    ) -> list[gtsam.NonlinearFactor]:
        m = _four_dof_measurement(R, tilts, i, T_i_j)
        t = m.R_tilt_i @ m.t_ij  # j's position in i's yaw-only frame
        C = np.zeros((4, 4))
        C[:3, :3] = m.R_tilt_i @ cov[:3, :3] @ m.R_tilt_i.T
        C[:3, 3] = C[3, :3] = m.R_tilt_i @ cov[:3, 3]
        C[3, 3] = cov[3, 3]
        xy_yaw = np.ix_([0, 1, 3], [0, 1, 3])
        n2, nz = _noise(C[xy_yaw]), _noise(C[2:3, 2:3])
        if robust:
            n2, nz = _robust(config, n2), _robust(config, nz)
        return [
            gtsam.BetweenFactorPose2(i, j, gtsam.Pose2(t[0], t[1], m.dyaw_rad), n2),
            gtsam.BetweenFactorDouble(N + i, N + j, float(t[2]), nz),
        ]

    def fixed(n: int) -> list[gtsam.NonlinearFactor]:
        return [
            gtsam.PriorFactorPose2(n, values.atPose2(n), _fixed_noise(3)),
            gtsam.PriorFactorDouble(N + n, values.atDouble(N + n), _fixed_noise(1)),
        ]

    return edge, fixed, tilts


def _se3(
    config: PoseGraphConfig, R: FloatArray, p: FloatArray, values: gtsam.Values
) -> tuple[_Edge, _Fixed, list[FloatArray]]:
    for n in range(len(p)):
        values.insert(n, gtsam.Pose3(gtsam.Rot3(R[n]), p[n]))

    def edge(
        i: int, j: int, T_i_j: gtsam.Pose3, _s: float, cov: FloatArray, robust: bool
    ) -> list[gtsam.NonlinearFactor]:
        noise = _robust(config, _noise(cov)) if robust else _noise(cov)
        return [gtsam.BetweenFactorPose3(i, j, T_i_j, noise)]

    def fixed(n: int) -> list[gtsam.NonlinearFactor]:
        return [gtsam.PriorFactorPose3(n, values.atPose3(n), _fixed_noise(6))]

    return edge, fixed, []


def _sim3(
    config: PoseGraphConfig, R: FloatArray, p: FloatArray, values: gtsam.Values
) -> tuple[_Edge, _Fixed, list[FloatArray]]:
    for n in range(len(p)):
        values.insert(n, gtsam.Similarity3(gtsam.Rot3(R[n]), p[n], 1.0))

    def edge(
        i: int, j: int, T_i_j: gtsam.Pose3, s: float, cov: FloatArray, robust: bool
    ) -> list[gtsam.NonlinearFactor]:
        noise = _robust(config, _noise(cov)) if robust else _noise(cov)
        S = gtsam.Similarity3(T_i_j.rotation(), T_i_j.translation(), s)
        return [gtsam.BetweenFactorSimilarity3(i, j, S, noise)]

    def fixed(n: int) -> list[gtsam.NonlinearFactor]:
        return [gtsam.PriorFactorSimilarity3(n, values.atSimilarity3(n), _fixed_noise(7))]

    return edge, fixed, []


def _builder(config: PoseGraphConfig) -> Callable[..., tuple[_Edge, _Fixed, list[FloatArray]]]:
    if config.kind == "4dof":
        return _four_dof if config.four_dof_factor == "custom" else _four_dof_native
    return _se3 if config.kind == "se3" else _sim3


def build_graph(
    problem: PoseGraphProblem,
) -> tuple[
    gtsam.NonlinearFactorGraph, gtsam.Values, list[list[gtsam.NonlinearFactor]], list[FloatArray]
]:
    """The factor graph, its initial values, each loop's factors without their robust kernel (to
    read their residuals back) and, for 4-DoF, the tilts held."""
    config = problem.config
    R = Rotation.from_quat(problem.quats_xyzw).as_matrix()
    T = [gtsam.Pose3(gtsam.Rot3(R[n]), problem.positions[n]) for n in range(len(R))]
    values = gtsam.Values()
    edge, fixed, tilts = _builder(config)(config, R, problem.positions, values)
    graph = gtsam.NonlinearFactorGraph()
    factors = []
    for i, j, _k, cov in sequential_covariances(problem):
        factors += edge(i, j, T[i].between(T[j]), 1.0, cov, False)
    pos = {int(k): n for n, k in enumerate(problem.indices)}
    plain = []
    for e in problem.loops:
        i, j, cov = pos[e.old], pos[e.new], _loop_cov(config, e)
        factors += edge(i, j, pose3(e.T_old_new), e.scale, cov, True)
        plain.append(edge(i, j, pose3(e.T_old_new), e.scale, cov, False))
    held = set(anchors(problem))
    if problem.fixed is not None:
        held |= set(np.flatnonzero(problem.fixed).tolist())
    for n in sorted(held):
        factors += fixed(n)
    for f in factors:
        graph.add(f)
    return graph, values, plain, tilts


def _read_back(
    problem: PoseGraphProblem, values: gtsam.Values, tilts: list[FloatArray]
) -> tuple[tuple[Pose, ...], FloatArray | None]:
    kind, n = problem.config.kind, len(problem.indices)
    if kind == "4dof":
        if problem.config.four_dof_factor == "custom":
            x = np.array([values.atVector(k) for k in range(n)])
        else:
            xy_yaw = [values.atPose2(k) for k in range(n)]
            x = np.array(
                [[q.x(), q.y(), values.atDouble(n + k), q.theta()] for k, q in enumerate(xy_yaw)]
            )
        R = Rotation.from_matrix(rot_z(x[:, 3]) @ np.array(tilts))
        return tuple(Pose(R[k], x[k, :3]) for k in range(n)), None
    if kind == "se3":
        return tuple(to_pose(values.atPose3(k)) for k in range(n)), None
    sims = [values.atSimilarity3(k) for k in range(n)]
    poses = tuple(to_pose(gtsam.Pose3(s.rotation(), s.translation())) for s in sims)
    return poses, np.array([s.scale() for s in sims], dtype=np.float64)


def levenberg_marquardt(
    graph: gtsam.NonlinearFactorGraph,
    initial: gtsam.Values,
    max_iterations: int,
    *,
    relative_tol: float = 1e-5,
    absolute_tol: float = 1e-5,
) -> tuple[gtsam.Values, int]:
    """Levenberg-Marquardt driven from Python: GTSAM linearises and solves each step, with the
    values held here (a ``CustomFactor`` then reads them without a copy). Damping ``lambda I``
    on every variable, from 1e-5, divided by 10 after a step that lowers the error and
    multiplied by 10 (up to 1e5 times) after one that does not; stops when the error falls by
    less than ``relative_tol`` (of itself) or ``absolute_tol``. Returns the values and the
    iterations."""
    values, error, lam = initial, graph.error(initial), 1e-5
    zero = initial.zeroVectors()
    dims = {k: zero.at(k).shape[0] for k in initial.keys()}  # noqa: SIM118 (Values is not iterable)
    unit = {d: gtsam.noiseModel.Unit.Create(d) for d in set(dims.values())}
    for iteration in range(1, max_iterations + 1):
        linear = graph.linearize(values)
        while lam < 1e5:
            damped = linear.clone()
            for k, d in dims.items():
                damped.add(
                    gtsam.JacobianFactor(k, math.sqrt(lam) * np.eye(d), np.zeros(d), unit[d])
                )
            trial = values.retract(damped.optimize())
            trial_error = graph.error(trial)
            if trial_error < error:
                lam /= 10.0
                break
            lam *= 10.0
        else:
            return values, iteration
        decrease, values, error = error - trial_error, trial, trial_error
        if decrease < absolute_tol or decrease < relative_tol * (error + decrease):
            return values, iteration
    return values, max_iterations


def solve(problem: PoseGraphProblem) -> PoseGraphResult:
    """Optimise ``problem`` (Levenberg-Marquardt) and return the corrected keyframe poses.

    A 4-DoF graph uses ``config.four_dof_factor``: ``custom``, our factor of VINS-Mono's error
    (:mod:`quadnav.posegraph.fourdof`), a Python callback per factor and linearisation; or
    ``native``, GTSAM's own factors on the same variables split in two: a ``Pose2`` (x, y, yaw)
    and a height. VINS-Mono's position residual rotated by the held tilt of i is the residual in
    i's yaw-only frame, ``rot_z(yaw_i)^T (p_j - p_i) - R_tilt_i t_ij``, whose (x, y) part and yaw
    ``BetweenFactorPose2`` measures (in its Lie chart: the same to first order in the residual
    yaw) and whose z part ``BetweenFactorDouble`` does. Differences: the robust kernel acts on the
    two parts apart, and a loop covariance's cross terms between z and the rest are dropped.
    ``benchmarks/posegraph.py`` measures both.

    The custom factor is solved by :func:`levenberg_marquardt`, not GTSAM's optimiser: inside
    it, each call of a ``CustomFactor`` gets a copy of all the values (the Python binding copies
    the optimiser's own ``Values`` to hand them over), so an iteration costs the square of the
    keyframes (1,000: 11 to 15 s a solve against 1.4 to 2.7 s so)."""
    t0 = time.perf_counter()
    graph, initial, plain, tilts = build_graph(problem)
    if problem.config.kind == "4dof" and problem.config.four_dof_factor == "custom":
        values, iterations = levenberg_marquardt(graph, initial, problem.config.max_iterations)
    else:
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(problem.config.max_iterations)
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
        values, iterations = optimizer.optimize(), optimizer.iterations()
    poses, scales = _read_back(problem, values, tilts)
    chi = np.array(
        [math.sqrt(2.0 * sum(f.error(values) for f in fs)) for fs in plain], dtype=np.float64
    )
    return PoseGraphResult(
        kind=problem.config.kind,
        indices=problem.indices,
        poses=poses,
        scales=scales,
        loop_chi=chi,
        initial_error=float(graph.error(initial)),
        final_error=float(graph.error(values)),
        iterations=int(iterations),
        solve_s=time.perf_counter() - t0,
    )
