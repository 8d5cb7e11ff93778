"""Loop closure judged against the ground truth (issue 23): each recognised place, precision,
recall, and the keyframes before and after the pose graph.

It reads arrays, runs nothing: the places a loop closer recognised (anything with the fields of
:class:`quadnav.loop.PlaceEvent`), the odometry's keyframes, the pose graph's corrected ones and
the ground truth (None for a recording without one: then only the counts and the top view).

Definitions (:class:`LoopEvalConfig`, one place for every threshold):

* two keyframes show **the same place** when the truth puts their bodies less than
  ``same_place_m`` (1 m) apart and turned less than ``same_place_yaw_deg`` (30 degrees) about
  the vertical from one another (a 75-degree camera turned by 30 degrees still sees most of
  what it saw);
* the **truth relative pose** of a place is ``T_old_new = T_W_old^-1 T_W_new`` from the truth
  at the two keyframes' times, body frames; the measured pose's **error** is its translation's
  distance from the truth's (m) and the angle of the rotation between the two (deg);
* an accepted loop is **true** when its measurement is within ``max_error_m`` (0.3 m) and
  ``max_error_deg`` (5 degrees) of the truth's relative pose: the edge it adds to the graph is
  right. A look-alike place measures a pose metres or tens of degrees off; a real one rarely
  more than a few centimetres. The keyframes need not pass the same-place test: two keyframes
  1.09 m apart seeing the same wall (room laps, seed 1) measured 2 cm off are a good loop, and
  the distance and yaw are in each place's score to be read. Every other accepted loop scored
  against the truth is **false**. **Precision** = true / (true + false);
* a keyframe **revisits** an earlier place when a keyframe at least ``exclude_keyframes``
  (the detector's excluded recent window, 30) before it shows the same place; it is **found**
  when a true loop was closed at a keyframe within ``recall_window`` keyframes of it (the
  closer closes at most one loop per ``min_keyframes_between`` keyframes, 5, so a revisit is
  not missed because its neighbour closed the loop). **Recall** = found / revisits.

:func:`revisit_bound` is the one part that solves something: the keyframes' error a pose graph
reaches when every revisit the truth shows is closed (one loop per ``every`` keyframes, to the
nearest earlier keyframe of the same place) and measured exactly (the truth's relative pose,
held to a centimetre). No place recognition or verification does better with that odometry and
that graph: it says whether the loops or the odometry between them hold the error.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import EvalError
from quadnav.eval.align import align
from quadnav.eval.na import Metric, na, rms_or_na
from quadnav.geometry.trajectory import Trajectory
from quadnav.units import NS_PER_S

if TYPE_CHECKING:
    from quadnav.posegraph import PoseGraphConfig

__all__ = [
    "LoopEvalConfig",
    "LoopEvaluation",
    "PlaceLike",
    "PlaceScore",
    "evaluate_loops",
    "plot_loop_graph",
    "revisit_bound",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
#: Keyframes compared with all earlier ones at once (memory bounded however long the run: a
#: block of 128 against 10,000 keyframes holds 30 MB).
_ROW_BLOCK = 128


class PlaceLike(Protocol):
    """What a recognised place carries (:class:`quadnav.loop.PlaceEvent` has it)."""

    @property
    def old(self) -> int: ...
    @property
    def new(self) -> int: ...
    @property
    def t_old_ns(self) -> int: ...
    @property
    def t_new_ns(self) -> int: ...
    @property
    def stage(self) -> str: ...
    @property
    def n_pnp(self) -> int: ...
    @property
    def T_old_new(self) -> tuple[float, ...] | None: ...


@dataclass(frozen=True, slots=True, kw_only=True)
class LoopEvalConfig:
    """The thresholds of the module's definitions."""

    same_place_m: float = 1.0
    same_place_yaw_deg: float = 30.0
    max_error_m: float = 0.3
    max_error_deg: float = 5.0
    exclude_keyframes: int = 30
    recall_window: int = 5

    def __post_init__(self) -> None:
        for name in ("same_place_m", "same_place_yaw_deg", "max_error_m", "max_error_deg"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise EvalError(f"LoopEvalConfig.{name} must be finite and > 0, got {value}")
        if self.exclude_keyframes < 1 or self.recall_window < 0:
            raise EvalError(
                "LoopEvalConfig.exclude_keyframes must be >= 1 and recall_window >= 0, got "
                f"{self.exclude_keyframes} and {self.recall_window}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class PlaceScore:
    """One recognised place judged: its keyframes and times, the stage it stopped at, the PnP
    inliers; with a truth, how far apart and turned the keyframes truly were (``same_place``),
    and for an accepted loop its measurement's error; ``correction_m``: how far the loop moved
    the new keyframe from where the odometry had it relative to the old (None: unknown);
    ``verdict``: ``true``, ``false``, ``accepted`` (no truth), ``rejected, same place``,
    ``rejected, another place`` or ``rejected``."""

    old: int
    new: int
    t_old_ns: int
    t_new_ns: int
    stage: str
    n_pnp: int
    truth_distance_m: float | None = None
    truth_yaw_deg: float | None = None
    same_place: bool | None = None
    error_m: float | None = None
    error_deg: float | None = None
    correction_m: float | None = None
    verdict: str = ""

    @property
    def accepted(self) -> bool:
        return self.stage == "accepted"


@dataclass(frozen=True, slots=True, kw_only=True)
class LoopEvaluation:
    """The places judged, the counts, precision and recall (``n/a: why`` without a truth or
    without anything to count), the measurements' median errors, and the keyframes for the
    figure: odometry and corrected, each aligned to the truth in position and yaw as the run's
    APE is (as they are without a truth), with their position errors (m) at ``error_t_ns`` and
    ``error_after_t_ns``."""

    config: LoopEvalConfig
    places: tuple[PlaceScore, ...]
    has_truth: bool
    accepted: int
    rejected: int
    true: Metric
    false: Metric
    precision: Metric
    revisits: Metric
    found: Metric
    recall: Metric
    rejected_same_place: Metric
    error_median_m: Metric
    error_median_deg: Metric
    keyframes: Trajectory
    corrected: Trajectory | None
    truth: Trajectory | None
    error_t_ns: IntArray
    error_before_m: FloatArray | None
    error_after_t_ns: IntArray
    error_after_m: FloatArray | None
    bound_m: Metric = "n/a: not computed"

    def as_metrics(self) -> dict[str, Metric | int]:
        """The ``loop_*`` entries of a run's ``metrics.json``."""
        before = _rms(self.error_before_m)
        after = _rms(self.error_after_m)
        return {
            "loop_accepted": self.accepted, "loop_rejected": self.rejected,
            "loop_true": self.true, "loop_false": self.false, "loop_precision": self.precision,
            "loop_revisits": self.revisits, "loop_revisits_found": self.found,
            "loop_recall": self.recall, "loop_rejected_same_place": self.rejected_same_place,
            "loop_measurement_error_median_m": self.error_median_m,
            "loop_measurement_error_median_deg": self.error_median_deg,
            "loop_keyframes_ape_rmse_before_m": before, "loop_keyframes_ape_rmse_after_m": after,
            "loop_keyframes_ape_rmse_bound_m": self.bound_m,
        }  # fmt: skip


def _rms(err: FloatArray | None) -> Metric:
    if err is None:
        return na("no ground truth for the keyframes")
    return rms_or_na(err, "no keyframe in the ground truth's span")


# -- geometry -------------------------------------------------------------------------------------


def _yaw_between_rad(q_a_xyzw: FloatArray, q_b_xyzw: FloatArray) -> FloatArray:
    """|turn about the world's z| from each attitude of ``q_a`` (m, 4) to each of ``q_b``
    (n, 4), (m, n) in [0, pi]: the twist about z of ``R_b R_a^-1`` (its swing-twist split),
    whatever way up the body frame is."""
    a = np.asarray(q_a_xyzw, dtype=np.float64)
    b = np.asarray(q_b_xyzw, dtype=np.float64)
    # the w and z parts of q_b (x) conj(q_a), each pair at once
    w = b @ a.T
    z = np.outer(b[:, 2], a[:, 3]) - np.outer(b[:, 3], a[:, 2])
    z += np.outer(b[:, 1], a[:, 0]) - np.outer(b[:, 0], a[:, 1])
    twist = 2.0 * np.arctan2(z, w)
    return np.abs((twist + np.pi) % (2.0 * np.pi) - np.pi)


def _truth_at(truth: Trajectory, t_ns: IntArray) -> tuple[NDArray[np.bool_], Trajectory | None]:
    """Which of ``t_ns`` the truth covers, and the truth there."""
    t = np.asarray(t_ns, dtype=np.int64)
    inside = (t >= truth.t_ns[0]) & (t <= truth.t_ns[-1]) if len(truth) >= 2 else t < t
    return inside, truth.interpolate(t[inside]) if inside.any() else None


def _rows_at(traj: Trajectory, t_ns: IntArray) -> IntArray:
    """The row of ``traj`` at each of ``t_ns`` (-1 where it has no pose at that time)."""
    t = np.asarray(t_ns, dtype=np.int64)
    k = np.clip(np.searchsorted(traj.t_ns, t), 0, max(len(traj) - 1, 0))
    ok = traj.t_ns[k] == t if len(traj) else np.zeros(len(t), bool)
    return np.where(ok, k, -1).astype(np.int64)


def _relative(traj: Trajectory, i: int, j: int) -> tuple[FloatArray, Rotation]:
    """Pose of row ``j`` in the body frame of row ``i``: translation and rotation."""
    R_i = Rotation.from_quat(traj.q_W_B_xyzw[i])
    R_j = Rotation.from_quat(traj.q_W_B_xyzw[j])
    return R_i.inv().apply(traj.p_W_B[j] - traj.p_W_B[i]), R_i.inv() * R_j


# -- the places -----------------------------------------------------------------------------------


def _score_place(
    p: PlaceLike, truth: Trajectory | None, odometry: Trajectory, cfg: LoopEvalConfig
) -> PlaceScore:
    score = PlaceScore(
        old=p.old, new=p.new, t_old_ns=p.t_old_ns, t_new_ns=p.t_new_ns, stage=p.stage,
        n_pnp=p.n_pnp,
    )  # fmt: skip
    accepted = p.stage == "accepted" and p.T_old_new is not None
    meas = np.asarray(p.T_old_new, dtype=np.float64) if accepted else None
    rows = _rows_at(odometry, np.array([p.t_old_ns, p.t_new_ns]))
    correction = None
    if meas is not None and (rows >= 0).all():
        t_odo, _ = _relative(odometry, int(rows[0]), int(rows[1]))
        correction = float(np.linalg.norm(meas[:3] - t_odo))
    inside, at = (
        _truth_at(truth, np.array([p.t_old_ns, p.t_new_ns])) if truth is not None else (None, None)
    )
    if at is None or inside is None or not inside.all():
        verdict = "accepted" if accepted else "rejected"
        return replace(score, correction_m=correction, verdict=verdict)
    dist = float(np.linalg.norm(at.p_W_B[1] - at.p_W_B[0]))
    yaw = float(np.degrees(_yaw_between_rad(at.q_W_B_xyzw[:1], at.q_W_B_xyzw[1:])[0, 0]))
    same = dist < cfg.same_place_m and yaw < cfg.same_place_yaw_deg
    if meas is None:
        verdict = "rejected, same place" if same else "rejected, another place"
        return replace(score, truth_distance_m=dist, truth_yaw_deg=yaw, same_place=same,
                     verdict=verdict)  # fmt: skip
    t_true, R_true = _relative(at, 0, 1)
    err_m = float(np.linalg.norm(meas[:3] - t_true))
    err_deg = float(np.degrees((R_true.inv() * Rotation.from_quat(meas[3:])).magnitude()))
    true = err_m < cfg.max_error_m and err_deg < cfg.max_error_deg
    return replace(
        score, truth_distance_m=dist, truth_yaw_deg=yaw, same_place=same, error_m=err_m,
        error_deg=err_deg, correction_m=correction, verdict="true" if true else "false",
    )  # fmt: skip


# -- recall ---------------------------------------------------------------------------------------


def _revisits(truth_kf: Trajectory, rows: IntArray, cfg: LoopEvalConfig) -> NDArray[np.bool_]:
    """Which keyframes (truth poses ``truth_kf`` at keyframe rows ``rows``) revisit a place
    shown by a keyframe at least ``exclude_keyframes`` rows before them."""
    n = len(rows)
    out = np.zeros(n, bool)
    p, q = truth_kf.p_W_B, truth_kf.q_W_B_xyzw
    yaw_max = np.radians(cfg.same_place_yaw_deg)
    for a in range(0, n, _ROW_BLOCK):
        b = min(n, a + _ROW_BLOCK)
        m = int(np.searchsorted(rows, rows[b - 1] - cfg.exclude_keyframes, side="right"))
        if m == 0:
            continue  # nothing far enough back yet
        near = np.linalg.norm(p[a:b, None, :] - p[None, :m, :], axis=2) < cfg.same_place_m
        near &= _yaw_between_rad(q[:m], q[a:b]) < yaw_max
        near &= rows[None, :m] <= rows[a:b, None] - cfg.exclude_keyframes
        out[a:b] = near.any(axis=1)
    return out


def _recall(
    truth: Trajectory, keyframes: Trajectory, places: Sequence[PlaceScore], cfg: LoopEvalConfig
) -> tuple[int, int]:
    """Keyframes that revisit an earlier place, and of them those found by a true loop."""
    inside, at = _truth_at(truth, keyframes.t_ns)
    if at is None:
        return 0, 0
    rows = np.flatnonzero(inside).astype(np.int64)
    revisit = _revisits(at, rows, cfg)
    closed = _rows_at(keyframes, np.array([s.t_new_ns for s in places if s.verdict == "true"]))
    closed = closed[closed >= 0]
    if len(closed) == 0:
        return int(revisit.sum()), 0
    gap = np.abs(rows[revisit][:, None] - closed[None, :]).min(axis=1)
    return int(revisit.sum()), int((gap <= cfg.recall_window).sum())


def _revisit_pairs(truth_kf: Trajectory, cfg: LoopEvalConfig, every: int) -> list[tuple[int, int]]:
    """``(old, new)`` rows: each keyframe that revisits a place (as :func:`_revisits`) and the
    nearest earlier keyframe of it, at most one every ``every`` keyframes."""
    p, q = truth_kf.p_W_B, truth_kf.q_W_B_xyzw
    yaw_max = np.radians(cfg.same_place_yaw_deg)
    out: list[tuple[int, int]] = []
    for j in range(cfg.exclude_keyframes, len(p)):
        if out and j - out[-1][1] < every:
            continue
        m = j - cfg.exclude_keyframes + 1
        d = np.linalg.norm(p[:m] - p[j], axis=1)
        ok = (d < cfg.same_place_m) & (_yaw_between_rad(q[:m], q[j : j + 1])[0] < yaw_max)
        if ok.any():
            out.append((int(np.flatnonzero(ok)[np.argmin(d[ok])]), j))
    return out


def revisit_bound(
    keyframes: Trajectory, truth: Trajectory | None, graph: PoseGraphConfig,
    config: LoopEvalConfig | None = None, *, step_var: FloatArray | None = None,
    segments: IntArray | None = None, every: int = 5, sigma_m: float = 0.01,
    sigma_yaw_rad: float = 0.005,
) -> Metric:  # fmt: skip
    """The keyframes' position RMSE (m; 4-DoF aligned as the run's APE) after a pose graph
    ``graph`` with a loop at every revisit the truth shows, measured from the truth and held to
    ``sigma_m`` and ``sigma_yaw_rad`` (see the module); ``step_var``: the odometry's variance
    growth per keyframe, as the run's graph had it; ``segments``: each keyframe's odometry
    frame (no sequential edge joins two: an odometry reset, a gap in the images; None: one
    frame). ``n/a`` without a truth or a revisit."""
    from quadnav.geometry.rotations import Pose
    from quadnav.posegraph import LoopEdge, PoseGraphProblem, solve

    cfg = config or LoopEvalConfig()
    if truth is None:
        return na("no ground truth")
    inside, at = _truth_at(truth, keyframes.t_ns)
    if at is None or inside.sum() < 2:
        return na("no keyframe in the ground truth's span")
    rows = np.flatnonzero(inside)
    kf = keyframes.select(rows)
    pairs = _revisit_pairs(at, cfg, every)
    if not pairs:
        return na("no keyframe revisits an earlier place")
    cov = (
        np.diag([sigma_m**2] * 3 + [sigma_yaw_rad**2]) if graph.kind == "4dof"
        else np.diag([sigma_yaw_rad**2] * 3 + [sigma_m**2] * 3 + [1e-6] * (graph.kind == "sim3"))
    )  # fmt: skip
    poses = [Pose(Rotation.from_quat(kf.q_W_B_xyzw[n]), kf.p_W_B[n]) for n in range(len(kf))]
    truths = [Pose(Rotation.from_quat(at.q_W_B_xyzw[n]), at.p_W_B[n]) for n in range(len(at))]
    loops = [LoopEdge(old=i, new=j, T_old_new=truths[i].inverse() @ truths[j], cov=cov)
             for i, j in pairs]  # fmt: skip
    steps = None if step_var is None else np.asarray(step_var, dtype=np.float64)[rows]
    frames = None if segments is None else np.asarray(segments, dtype=np.int64)[rows]
    problem = PoseGraphProblem.from_poses(
        range(len(kf)), poses, loops, config=graph, step_var=steps, reset_counters=frames
    )
    result = solve(problem)
    fixed = Trajectory(
        t_ns=kf.t_ns, p_W_B=result.positions(),
        q_W_B_xyzw=np.array([p.R_A_B.as_quat() for p in result.poses]), name="keyframes_bound",
    )  # fmt: skip
    _, err, _ = _aligned(truth, fixed)
    return _rms(err)


# -- the keyframes before and after ---------------------------------------------------------------


def _aligned(
    truth: Trajectory | None, traj: Trajectory | None
) -> tuple[Trajectory | None, FloatArray | None, IntArray]:
    """``traj`` where the truth covers it, aligned in position and yaw (``4dof``, as the run's
    APE), and its position errors; ``traj`` as it is (no errors) without a truth."""
    none = np.zeros(0, dtype=np.int64)
    if traj is None or truth is None:
        return traj, None, none
    inside, at = _truth_at(truth, traj.t_ns)
    if at is None or inside.sum() < 2:
        return traj, None, none
    sel = traj.select(np.flatnonzero(inside))
    try:
        aligned, _ = align(at, sel, "4dof")
    except EvalError:
        return traj, None, none
    return aligned, np.linalg.norm(aligned.p_W_B - at.p_W_B, axis=1), at.t_ns


def evaluate_loops(
    places: Sequence[PlaceLike],
    keyframes: Trajectory,
    corrected: Trajectory | None,
    truth: Trajectory | None,
    config: LoopEvalConfig | None = None,
) -> LoopEvaluation:
    """The places judged and counted, precision and recall (see the module): ``keyframes``
    the odometry's, ``corrected`` the pose graph's (None: none), ``truth`` the ground truth
    (None: a recording without one)."""
    cfg = config or LoopEvalConfig()
    scores = tuple(_score_place(p, truth, keyframes, cfg) for p in places)
    accepted = sum(s.accepted for s in scores)
    kf_aligned, before, t_err = _aligned(truth, keyframes)
    corr_aligned, after, t_after = _aligned(truth, corrected)
    counts = _counts(truth, keyframes, scores, cfg)
    return LoopEvaluation(
        config=cfg, places=scores, has_truth=truth is not None, accepted=accepted,
        rejected=len(scores) - accepted, true=counts[0], false=counts[1], precision=counts[2],
        revisits=counts[3], found=counts[4], recall=counts[5], rejected_same_place=counts[6],
        error_median_m=counts[7], error_median_deg=counts[8], keyframes=kf_aligned or keyframes,
        corrected=corr_aligned,
        truth=truth.interpolate(t_err) if truth is not None and len(t_err) else None,
        error_t_ns=t_err, error_before_m=before, error_after_t_ns=t_after, error_after_m=after,
    )  # fmt: skip


def _counts(
    truth: Trajectory | None,
    keyframes: Trajectory,
    scores: Sequence[PlaceScore],
    cfg: LoopEvalConfig,
) -> tuple[Metric, ...]:
    """True, false, precision, revisits, found, recall, rejected at the same place, and the
    median measurement errors (m, deg); each ``n/a`` without a truth."""
    if truth is None:
        return (na("no ground truth"),) * 9
    true = sum(s.verdict == "true" for s in scores)
    false = sum(s.verdict == "false" for s in scores)
    revisits, found = _recall(truth, keyframes, scores, cfg)
    err = np.array([(s.error_m, s.error_deg) for s in scores if s.error_m is not None])
    none = na("no loop accepted in the truth's span")
    return (
        true, false, true / (true + false) if true + false else none,
        revisits, found,
        found / revisits if revisits else na("no keyframe revisits an earlier place"),
        sum(s.verdict == "rejected, same place" for s in scores),
        float(np.median(err[:, 0])) if len(err) else none,
        float(np.median(err[:, 1])) if len(err) else none,
    )  # fmt: skip


# -- the figure -----------------------------------------------------------------------------------


def _positions(traj: Trajectory, t_ns: Sequence[int]) -> FloatArray:
    rows = _rows_at(traj, np.array(t_ns, dtype=np.int64))
    out = np.full((len(rows), 3), np.nan)
    out[rows >= 0] = traj.p_W_B[rows[rows >= 0]]
    return out


_EDGE_STYLE = {"true": "tab:green", "false": "tab:red", "accepted": "k"}
#: a rejected candidate's marker at its new keyframe: style, colour, legend
_REJECTED_STYLE = {
    "rejected": ("x", "tab:purple", "candidate rejected"),
    "rejected, another place": ("x", "tab:purple", "candidate rejected (another place)"),
    "rejected, same place": ("o", "tab:brown", "candidate rejected (a real revisit)"),
}


def _draw_top(ax: Any, ev: LoopEvaluation) -> None:
    from quadnav.eval.plots import thinned

    lines = ((ev.truth, "--", "0.5", "ground truth (at the keyframes)"),
             (ev.keyframes, "-", "tab:blue", "odometry keyframes"),
             (ev.corrected, "-", "tab:orange", "after the pose graph"))  # fmt: skip
    for tr, style, colour, label in lines:
        if tr is not None and len(tr):
            p = tr.p_W_B[thinned(len(tr))]
            ax.plot(p[:, 0], p[:, 1], style, color=colour, lw=1.0, label=label)
    on = ev.corrected if ev.corrected is not None else ev.keyframes
    drawn: set[str] = set()
    for s in ev.places:
        a, b = _positions(on, [s.t_old_ns, s.t_new_ns])
        if s.accepted:
            colour = _EDGE_STYLE.get(s.verdict, "k")
            edge = None if s.verdict in drawn else f"loop ({s.verdict})"
            drawn.add(s.verdict)
            ax.plot([a[0], b[0]], [a[1], b[1]], "-", color=colour, lw=1.2, label=edge)
        else:
            look = _REJECTED_STYLE.get(s.verdict, _REJECTED_STYLE["rejected"])
            mark = None if s.verdict in drawn else look[2]
            drawn.add(s.verdict)
            ax.plot([b[0]], [b[1]], look[0], color=look[1], ms=6, mfc="none", label=mark)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    what = "aligned to the truth in position and yaw" if ev.has_truth else "no ground truth"
    ax.set_title(f"Keyframes and loops from above ({what})")


def _draw_errors(ax: Any, ev: LoopEvaluation, t0_ns: int) -> None:
    for t_ns, err, colour, label in (
        (ev.error_t_ns, ev.error_before_m, "tab:blue", "odometry"),
        (ev.error_after_t_ns, ev.error_after_m, "tab:orange", "after the pose graph"),
    ):
        if err is not None:
            ax.plot((t_ns - t0_ns) / NS_PER_S, err, "-", color=colour, lw=1.0, label=label)
    for k, s in enumerate(s for s in ev.places if s.accepted):
        ax.axvline((s.t_new_ns - t0_ns) / NS_PER_S, color=_EDGE_STYLE.get(s.verdict, "k"),
                   lw=0.6, alpha=0.6, label="loop closed" if k == 0 else None)  # fmt: skip
    ax.set_xlabel("t (s from the run's start)")
    ax.set_ylabel("keyframe position error (m)")
    ax.set_title("Keyframe error before and after the pose graph")


def plot_loop_graph(ev: LoopEvaluation, path: Path, t0_ns: int) -> Path:
    """``path`` (PNG): the top view of the truth, the odometry's and the corrected keyframes,
    the accepted loops (green true, red false, black without a truth) and the rejected
    candidates; beside it, with a truth, the keyframes' position error against time before and
    after the pose graph, the loops marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with_errors = ev.error_before_m is not None
    fig, axes = plt.subplots(
        1, 2 if with_errors else 1, figsize=(14 if with_errors else 7.5, 5.5),
        constrained_layout=True, squeeze=False,
    )  # fmt: skip
    _draw_top(axes[0, 0], ev)
    if with_errors:
        _draw_errors(axes[0, 1], ev, t0_ns)
    for ax in axes[0]:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
