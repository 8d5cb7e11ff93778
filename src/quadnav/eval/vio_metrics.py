"""Metrics of a visual-inertial odometry run, as VIO papers report them (pure functions).

- APE after a 4-DoF (position + yaw) alignment, the four directions VIO cannot observe; SE(3)
  and Sim(3) alignments beside it for reference (Sim(3)'s scale says how metric the run was).
- RPE by evo's definitions (:func:`quadnav.eval.metrics.rpe`), over pairs a length of the
  ground truth's path apart (the distance really travelled, whatever the estimate's scale).
- Drift in % of the distance travelled, two ways, each named: ``final``: the last pose's error
  after aligning the estimate on its first seconds only (yaw and position of the attitudes and
  positions there, so a start at rest aligns too); ``rpe``: the mean translation RPE over pairs
  ``d`` metres of path apart, over ``d``.
- Gravity error: the angle between the estimate's and the truth's gravity direction in the body
  frame, at the first estimate (yaw does not enter).
- NEES of the 6-DoF pose covariance in GTSAM's convention (body frame, (rot, trans), ``T_true =
  T_est Exp(xi)``) against the truth, the estimate aligned in yaw and position on its first
  pose: the estimator fixes those four unobservable directions with a prior on its first state,
  so its covariance is that of the error since then, growing with the drift; an alignment over
  the whole run would take the mean drift off and leave the start with an error its small
  covariance could never hold. Mean NEES / 6 (1 is consistent) with the chi-square 95 % band
  of that mean, and the fraction of frames inside one draw's 95 % band. Consecutive frames'
  errors are correlated, so the band of a single run is optimistic: over seeds the means are
  the honest test. An odometry whose world is not levelled (a SLAM's: its first camera's) fixes
  all six directions at its first pose instead; its NEES is taken after aligning that whole
  pose (``levelled=False``): aligned in yaw only, the start's tilt would count as its error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import EvalError
from quadnav.estimation.chi2 import chi2_ppf
from quadnav.eval.align import AlignMethod, align
from quadnav.eval.metrics import ErrorStats, ape, rpe
from quadnav.eval.na import Metric, na
from quadnav.geometry.trajectory import Trajectory
from quadnav.units import s_to_ns

__all__ = [
    "MIN_DRIFT_DISTANCE_M",
    "MIN_SCORED_POSES",
    "ApeSummary",
    "NeesSummary",
    "RpeSummary",
    "RunCounts",
    "VioMetrics",
    "ape_summary",
    "drift_final_pct",
    "drift_rpe_pct",
    "final_error_m",
    "gravity_error_deg",
    "in_estimator_gauge",
    "nees_band",
    "pose_covariances",
    "pose_nees",
    "pose_nees_parts",
    "pose_nees_summary",
    "vio_metrics",
    "yaw_position_alignment",
]

FloatArray = NDArray[np.float64]

#: Pose dimension of the NEES (rotation 3 + translation 3).
POSE_DOF = 6
#: The fewest matched poses a run is scored on: an alignment of 2 or 3 poses fits them exactly.
MIN_SCORED_POSES = 10
#: The shortest path a drift in % of the distance travelled is given for: over millimetres (a
#: vehicle at rest) any error is a huge percentage of nothing.
MIN_DRIFT_DISTANCE_M = 1.0


@dataclass(frozen=True, slots=True, kw_only=True)
class ApeSummary:
    """Translation APE (m) after one alignment: the statistics VIO users compare, and the scale
    the alignment found (1 except for Sim(3))."""

    alignment: AlignMethod
    rmse_m: float
    mean_m: float
    median_m: float
    max_m: float
    scale: float
    poses: int


@dataclass(frozen=True, slots=True, kw_only=True)
class RpeSummary:
    """RPE over pairs ``delta_m`` metres of the ground truth's path apart (evo's all pairs): translation (m) and
    rotation (deg) RMSE and mean."""

    delta_m: float
    pairs: int
    trans_rmse_m: float
    trans_mean_m: float
    rot_rmse_deg: float
    rot_mean_deg: float


@dataclass(frozen=True, slots=True, kw_only=True)
class NeesSummary:
    """Pose NEES over ``samples`` frames: ``mean_over_dof`` (1 consistent), the 95 % band of
    that mean for independent draws, and the fraction of frames inside one draw's 95 % band
    (0.95 consistent)."""

    samples: int
    mean_over_dof: float
    band_low: float
    band_high: float
    fraction_in_band: float


@dataclass(frozen=True, slots=True, kw_only=True)
class VioMetrics:
    """What ``metrics.json`` of a VIO run holds. A metric the run gives nothing to compute is
    ``"n/a: why"`` (no ground truth, no estimate, too short a path)."""

    frames: int
    frames_with_estimate: int
    fraction_with_estimate: float
    failures: int
    reinitializations: int
    rejected_images: int
    initialized_after_s: Metric
    #: solves the estimator recovered from without breaking its output (``recovered`` events)
    recoveries: int = 0
    distance_m: Metric
    ape_4dof: ApeSummary | str
    ape_se3: ApeSummary | str
    ape_sim3: ApeSummary | str
    rpe_1m: RpeSummary | str
    rpe_10m: RpeSummary | str
    final_error_m: Metric
    drift_final_pct: Metric
    drift_rpe_pct: Metric
    drift_definitions: str
    gravity_error_deg: Metric
    nees_pose: NeesSummary | str


def ape_summary(ref: Trajectory, est: Trajectory, method: AlignMethod) -> ApeSummary:
    """Translation APE of matched ``ref``/``est`` after aligning the estimate by ``method``."""
    aligned, a = align(ref, est, method)
    s = ErrorStats.of(ape(ref, aligned))
    return ApeSummary(
        alignment=method, rmse_m=s.rmse, mean_m=s.mean, median_m=s.median, max_m=s.max,
        scale=a.s, poses=len(est),
    )  # fmt: skip


def yaw_position_alignment(
    ref: Trajectory, est: Trajectory, first_s: float
) -> tuple[Rotation, FloatArray]:
    """The yaw and translation taking ``est`` onto ``ref`` from the matched poses of the first
    ``first_s`` seconds: the circular mean of the attitudes' yaw differences, then the mean
    position difference. Unlike a fit to positions it is defined at rest."""
    if len(ref) != len(est) or len(est) == 0:
        raise EvalError("the drift alignment needs matched, non-empty trajectories")
    end = est.t_ns[0] + s_to_ns(first_s) if math.isfinite(first_s) else est.t_ns[-1]
    n = max(1, int(np.searchsorted(est.t_ns, end, side="right")))
    d = ref.R_W_B[:n] * est.R_W_B[:n].inv()
    x = d.apply(np.array([1.0, 0.0, 0.0]))  # a yaw difference turns x about z
    yaw = math.atan2(float(x[:, 1].sum()), float(x[:, 0].sum()))
    R = Rotation.from_euler("z", yaw)
    t = np.mean(ref.p_W_B[:n] - R.apply(est.p_W_B[:n]), axis=0)
    return R, np.asarray(t, dtype=np.float64)


def first_pose_alignment(ref: Trajectory, est: Trajectory) -> tuple[Rotation, FloatArray]:
    """The rotation and translation taking ``est``'s first pose onto ``ref``'s: the gauge of an
    odometry whose world is its first pose, tilt and all."""
    if len(ref) != len(est) or len(est) == 0:
        raise EvalError("the first-pose alignment needs matched, non-empty trajectories")
    R = ref.R_W_B[0] * est.R_W_B[0].inv()
    t = ref.p_W_B[0] - R.apply(est.p_W_B[0])
    return R, np.asarray(t, dtype=np.float64)


def final_error_m(ref: Trajectory, est: Trajectory, *, first_s: float = 2.0) -> float:
    """The last pose's position error (m) after aligning on the first ``first_s`` seconds."""
    R, t = yaw_position_alignment(ref, est, first_s)
    return float(np.linalg.norm(ref.p_W_B[-1] - (R.apply(est.p_W_B[-1]) + t)))


def drift_final_pct(ref: Trajectory, est: Trajectory, *, first_s: float = 2.0) -> Metric:
    """:func:`final_error_m` in % of the distance the reference travelled; ``n/a`` for a path
    under :data:`MIN_DRIFT_DISTANCE_M`."""
    length = ref.path_length_m()
    if length < MIN_DRIFT_DISTANCE_M:
        return na(
            f"the ground truth travels {length:.2g} m, under the {MIN_DRIFT_DISTANCE_M:g} m a "
            "drift in % of the distance needs"
        )
    return 100.0 * final_error_m(ref, est, first_s=first_s) / length


def _rpe_summary(ref: Trajectory, est: Trajectory, delta_m: float) -> RpeSummary | str:
    if ref.path_length_m() < 2.0 * delta_m:
        return na(f"the path is shorter than {2 * delta_m:g} m")
    try:
        e_t, _ = rpe(
            ref,
            est,
            delta=delta_m,
            unit="metres",
            relation="trans",
            all_pairs=True,
            pairs_from="reference",
        )
        e_r, _ = rpe(
            ref,
            est,
            delta=delta_m,
            unit="metres",
            relation="rot",
            all_pairs=True,
            pairs_from="reference",
        )
    except EvalError as exc:
        return na(str(exc))
    if len(e_t) == 0:
        return na(f"no pair of poses {delta_m:g} m of path apart")
    st, sr = ErrorStats.of(e_t), ErrorStats.of(np.degrees(e_r))
    return RpeSummary(
        delta_m=delta_m, pairs=len(e_t), trans_rmse_m=st.rmse, trans_mean_m=st.mean,
        rot_rmse_deg=sr.rmse, rot_mean_deg=sr.mean,
    )  # fmt: skip


def drift_rpe_pct(rpe_summary: RpeSummary | str) -> Metric:
    """Mean translation RPE over pairs ``d`` metres apart, in % of ``d``."""
    if isinstance(rpe_summary, str):
        return rpe_summary
    return 100.0 * rpe_summary.trans_mean_m / rpe_summary.delta_m


def gravity_error_deg(R_W_B_est: Rotation, R_W_B_ref: Rotation) -> float:
    """Angle (deg) between the up direction each attitude puts in the body frame."""
    up = np.array([0.0, 0.0, 1.0])
    a, b = R_W_B_est.inv().apply(up), R_W_B_ref.inv().apply(up)
    return float(np.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), float(np.dot(a, b)))))


_TRIU = np.triu_indices(POSE_DOF)
#: Poses the NEES takes at once: its temporaries are ~1 kB a pose.
NEES_CHUNK = 8192


def pose_covariances(triu: FloatArray) -> FloatArray:
    """Symmetric (N, 6, 6) covariances from their upper triangles (N, 21), each row in
    ``np.triu_indices(6)``'s order (how a run keeps them: 168 bytes a pose, not 288)."""
    rows = np.asarray(triu, dtype=np.float64)
    cov = np.zeros((len(rows), POSE_DOF, POSE_DOF))
    cov[:, _TRIU[0], _TRIU[1]] = rows
    cov[:, _TRIU[1], _TRIU[0]] = rows
    return cov


def pose_nees(ref: Trajectory, est: Trajectory, cov_pose: FloatArray) -> FloatArray:
    """NEES per matched pose of the body-frame (rot, trans) covariances ``cov_pose``, (N, 6, 6)
    or their upper triangles (N, 21; :func:`pose_covariances`): ``xi = (Log(R_est^T R_ref),
    R_est^T (p_ref - p_est))``, GTSAM's right perturbation to first order in the translation.
    Taken :data:`NEES_CHUNK` poses at a time."""
    return pose_nees_parts(ref, est, cov_pose)[:, 0]


def pose_nees_parts(ref: Trajectory, est: Trajectory, cov_pose: FloatArray) -> FloatArray:
    """(N, 3): each matched pose's NEES (6 degrees of freedom, as :func:`pose_nees`), its
    rotation's and its translation's alone (3 each, on their marginal covariances): which
    part of an estimate is overconfident."""
    cov = np.asarray(cov_pose, dtype=np.float64)
    n = len(est)
    if len(ref) != n or cov.shape not in ((n, POSE_DOF, POSE_DOF), (n, len(_TRIU[0]))):
        raise EvalError(
            f"pose NEES needs matched poses and (N, 6, 6) or (N, 21) covariances, got "
            f"{len(ref)}, {n} poses and {cov.shape}"
        )
    out = np.empty((n, 3))
    for s in range(0, n, NEES_CHUNK):
        c = slice(s, s + NEES_CHUNK)
        out[c] = _nees_rows(ref.select(c), est.select(c), cov[c])
    return out


def _quadratic(cov: FloatArray, xi: FloatArray) -> FloatArray:
    try:
        sol = np.linalg.solve(cov, xi[..., None])[..., 0]
    except np.linalg.LinAlgError:
        raise EvalError("pose NEES: a covariance is singular") from None
    return np.asarray(np.sum(xi * sol, axis=1), dtype=np.float64)


def _nees_rows(ref: Trajectory, est: Trajectory, cov: FloatArray) -> FloatArray:
    if cov.ndim == 2:
        cov = pose_covariances(cov)
    R_est = est.R_W_B
    xi = np.hstack(
        [(R_est.inv() * ref.R_W_B).as_rotvec(), R_est.inv().apply(ref.p_W_B - est.p_W_B)]
    )
    return np.column_stack(
        [
            _quadratic(cov, xi),
            _quadratic(cov[:, :3, :3], xi[:, :3]),
            _quadratic(cov[:, 3:, 3:], xi[:, 3:]),
        ]
    )


def nees_band(samples: int, dof: int = POSE_DOF, confidence: float = 0.95) -> tuple[float, float]:
    """The two-sided band of the mean of ``samples`` independent NEES draws, over ``dof``."""
    lo, hi = chi2_ppf([(1 - confidence) / 2, (1 + confidence) / 2], dof * samples)
    return float(lo / (dof * samples)), float(hi / (dof * samples))


def pose_nees_summary(values: FloatArray) -> NeesSummary:
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 1 or len(v) == 0:
        raise EvalError("a NEES summary needs a non-empty 1-D array")
    lo, hi = nees_band(len(v))
    one_lo, one_hi = chi2_ppf([0.025, 0.975], POSE_DOF)
    inside = float(np.mean((v >= one_lo) & (v <= one_hi)))
    return NeesSummary(
        samples=len(v), mean_over_dof=float(np.mean(v)) / POSE_DOF, band_low=lo, band_high=hi,
        fraction_in_band=inside,
    )  # fmt: skip


DRIFT_DEFINITIONS = (
    "final_error_m, drift_final_pct: the last pose's position error after a yaw + position alignment on the "
    "first {first_s:g} s, in % of the distance travelled (n/a under {min_m:g} m travelled); "
    "drift_rpe_pct: mean translation RPE "
    "over pairs {delta:g} m of path apart (evo's all pairs), in % of {delta:g} m"
)


@dataclass(frozen=True, slots=True, kw_only=True)
class RunCounts:
    """What the run itself counted (no ground truth needed)."""

    frames: int
    failures: int
    reinitializations: int
    rejected_images: int
    initialized_after_s: Metric
    recoveries: int = 0


def _without_truth(est: Trajectory, counts: RunCounts, reason: str) -> VioMetrics:
    return VioMetrics(
        frames=counts.frames, frames_with_estimate=len(est),
        fraction_with_estimate=len(est) / counts.frames if counts.frames else 0.0,
        failures=counts.failures, reinitializations=counts.reinitializations,
        rejected_images=counts.rejected_images, initialized_after_s=counts.initialized_after_s,
        recoveries=counts.recoveries,
        distance_m=na(reason), ape_4dof=na(reason), ape_se3=na(reason), ape_sim3=na(reason),
        rpe_1m=na(reason), rpe_10m=na(reason), final_error_m=na(reason),
        drift_final_pct=na(reason),
        drift_rpe_pct=na(reason), drift_definitions="", gravity_error_deg=na(reason),
        nees_pose=na(reason),
    )  # fmt: skip


def _aligned_or_na(ref: Trajectory, est: Trajectory, method: AlignMethod) -> ApeSummary | str:
    try:
        return ape_summary(ref, est, method)
    except EvalError as exc:
        return na(str(exc))


def in_estimator_gauge(ref: Trajectory, est: Trajectory, levelled: bool = True) -> Trajectory:
    """``est`` moved into ``ref``'s frame the way its covariance allows: a levelled estimator's
    world is fixed up to yaw and position at its first pose, another's (a SLAM's first pose)
    in all six directions there (see the module)."""
    if levelled:
        R, t = yaw_position_alignment(ref, est, 0.0)
    else:
        R, t = first_pose_alignment(ref, est)
    return est.transformed(R, t)


def _nees_or_na(
    ref: Trajectory, est: Trajectory, cov: FloatArray | None, levelled: bool
) -> NeesSummary | str:
    if cov is None:
        return na("the estimate carries no pose covariance")
    try:
        return pose_nees_summary(pose_nees(ref, in_estimator_gauge(ref, est, levelled), cov))
    except EvalError as exc:
        return na(str(exc))


def vio_metrics(
    ref: Trajectory | None,
    est: Trajectory,
    counts: RunCounts,
    *,
    cov_pose: FloatArray | None = None,
    drift_first_s: float = 2.0,
    unscored: str = "the dataset has no ground truth",
    levelled: bool = True,
) -> VioMetrics:
    """Every metric of a run: ``ref`` the ground truth matched to ``est`` (equal length, same
    times; None when there is none to match, ``unscored`` saying why), ``cov_pose`` the
    estimate's (N, 6, 6), or their upper triangles (N, 21; :func:`pose_covariances`);
    ``levelled``: False for an odometry whose world is its first pose (see the module)."""
    if ref is None:
        return _without_truth(est, counts, unscored)
    if len(est) < MIN_SCORED_POSES:
        return _without_truth(
            est, counts,
            f"only {len(est)} estimated pose(s) match the ground truth ({MIN_SCORED_POSES} needed)",
        )  # fmt: skip
    if len(ref) != len(est):
        raise EvalError("vio_metrics needs the ground truth matched to the estimate")
    rpe_1, rpe_10 = _rpe_summary(ref, est, 1.0), _rpe_summary(ref, est, 10.0)
    rpe_for_drift, delta = (rpe_10, 10.0) if not isinstance(rpe_10, str) else (rpe_1, 1.0)
    return VioMetrics(
        frames=counts.frames, frames_with_estimate=len(est),
        fraction_with_estimate=len(est) / counts.frames if counts.frames else 0.0,
        failures=counts.failures, reinitializations=counts.reinitializations,
        rejected_images=counts.rejected_images, initialized_after_s=counts.initialized_after_s,
        recoveries=counts.recoveries,
        distance_m=ref.path_length_m(),
        ape_4dof=_aligned_or_na(ref, est, "4dof"), ape_se3=_aligned_or_na(ref, est, "se3"),
        ape_sim3=_aligned_or_na(ref, est, "sim3"), rpe_1m=rpe_1, rpe_10m=rpe_10,
        final_error_m=final_error_m(ref, est, first_s=drift_first_s),
        drift_final_pct=drift_final_pct(ref, est, first_s=drift_first_s),
        drift_rpe_pct=drift_rpe_pct(rpe_for_drift),
        drift_definitions=DRIFT_DEFINITIONS.format(
            first_s=drift_first_s, delta=delta, min_m=MIN_DRIFT_DISTANCE_M
        ),
        gravity_error_deg=gravity_error_deg(est.R_W_B[0], ref.R_W_B[0]),
        nees_pose=_nees_or_na(ref, est, cov_pose, levelled),
    )  # fmt: skip
