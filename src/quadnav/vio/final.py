"""The VIO's final trajectory: every tracked frame again, through its reference keyframe's
last pose (ORB-SLAM's saved trajectory; not causal).

A keyframe's last pose is where the window left it (the fixed-lag smoother's estimate when it
was marginalised) or, with ``VioConfig.final_smoothing``, where a smoothing over the whole run
puts it: each segment of the run (from a start, a restart in place or a re-initialisation to
the next) is its window's every factor again (each keyframe's IMU, its observations, the
landmarks' weak priors, the calibration's priors; not the marginal factors, which would count
the same information twice), optimised at once by Levenberg-Marquardt from the window's
estimates. A restart in place begins from keyframes the segment before also has: the later
segment is turned about the vertical and shifted onto the earlier one's smoothed pose of the
first keyframe they share (its position and heading; gravity fixes roll and pitch in both),
so the trajectory does not jump there. A segment whose smoothing fails keeps its
window's poses, and is counted.

With ``final_smoothing_accel_inflation`` over 1, the IMU factors are preintegrated again
there from the run's readings (:class:`ImuLog`) with the accelerometer's noise density
times it. On realistic sensors (an accelerometer at EuRoC's in-flight 0.062 m/s^2/sqrt(Hz)),
a smoothing that weighs it at its true level came out about 1 % too large in scale on V1_02's
motion, and 2 took that out; on MH_01's and corridor1's it cost more than it gave: measured
on the 2026-12-05 (session 29) results page.

With loop closure (``quadnav vio --loop --final-ba``), each verified loop between two
keyframes of one segment is a factor of that segment's smoothing too: the new keyframe's pose
relative to the old one's, at the loop's covariance, behind a Huber kernel
(:data:`LOOP_HUBER_K`), so the IMU and the images spread the drift the loop measured over the
keyframes between (ORB-SLAM3's global adjustment after a loop, here once at the end). Where
the loop says what it was measured from (the old side's landmarks and where the new keyframe
saw them), the segment holds those landmarks and an observer is given
(``VioConfig.loops_as_observations``), it enters as those observations instead: the new
keyframe's projection factors of the old landmarks, as ORB-SLAM's loop fusion joins the two
sides' map points before its global adjustment. The relative pose carries the old landmarks'
error with a guessed covariance (``LoopConfig.loop_floor_m``) and 4 degrees of freedom, not
a monocular run's scale; as observations the smoothing moves the landmarks too (on the whole
realistic MH_01, mono: 0.38x of no loops against 0.53x as relative poses). A loop between two
segments is not used, and is counted.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import VioError
from quadnav.geometry.gtsam_bridge import pose3
from quadnav.geometry.trajectory import Trajectory
from quadnav.messages import ImuSample
from quadnav.odometry import LoopConstraint
from quadnav.vio.graph import GTSAM_ERRORS, GraphHistory
from quadnav.vio.preintegration import preintegrate

__all__ = [
    "LOOP_HUBER_K",
    "FrameTrail",
    "ImuLog",
    "LoopObserver",
    "SmoothingReport",
    "loop_factor",
    "reweighed",
    "smooth_segments",
]

FloatArray = NDArray[np.float64]

#: a loop's residual (in its sigmas) beyond which its factor's weight falls as 1/residual
LOOP_HUBER_K = 2.0


@dataclass(frozen=True, slots=True)
class SmoothingReport:
    """What the final smoothing did: segments smoothed and failed, keyframes moved, the
    graphs' total error before and after (summed over the segments smoothed)."""

    segments: int = 0
    failed: int = 0
    keyframes: int = 0
    error_before: float = 0.0
    error_after: float = 0.0
    failures: tuple[str, ...] = ()
    #: loops given as factors, and those that were not (their keyframes in two segments)
    loops: int = 0
    loops_unused: int = 0
    #: of the loops given, those taken as observations of the segment's landmarks
    loops_observed: int = 0


def loop_factor(loop: LoopConstraint) -> gtsam.BetweenFactorPose3:
    """``loop`` as a factor between its keyframes' poses (keys ``x``), Huber-weighted."""
    noise = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(LOOP_HUBER_K),
        gtsam.noiseModel.Gaussian.Covariance(np.asarray(loop.cov, dtype=np.float64)),
    )
    return gtsam.BetweenFactorPose3(
        gtsam.symbol("x", loop.old), gtsam.symbol("x", loop.new), pose3(loop.T_old_new), noise
    )


#: what turns a loop into observations of the segment's own landmarks: the loop, and the keys
#: the segment's factors hold; no factors when too few of its landmarks are in the segment
LoopObserver = Callable[[LoopConstraint, set[int]], list[gtsam.NonlinearFactor]]


def _with_loops(
    seg: GraphHistory, loops: Sequence[LoopConstraint], observe: LoopObserver | None = None
) -> tuple[GraphHistory, set[tuple[int, int]], int]:
    """``seg`` with the loops whose two keyframes it holds as factors (the segment's own
    graph left as it is); which (old, new), and how many were taken as observations: each loop
    as the new keyframe's observations of the old landmarks (``observe``) where it can be, as
    a relative pose where it cannot."""
    mine = [
        lp for lp in loops
        if seg.values.exists(gtsam.symbol("x", lp.old))
        and seg.values.exists(gtsam.symbol("x", lp.new))
    ]  # fmt: skip
    if not mine:
        return seg, set(), 0
    graph = gtsam.NonlinearFactorGraph()
    graph.push_back(seg.factors)
    held = set(seg.factors.keys()) if observe is not None else set()
    observed = 0
    for lp in mine:
        factors = observe(lp, held) if observe is not None else []
        for f in factors:
            graph.add(f)
        if not factors:
            graph.add(loop_factor(lp))
        observed += bool(factors)
    return GraphHistory(graph, seg.values), {(lp.old, lp.new) for lp in mine}, observed


def smooth_segments(
    segments: list[GraphHistory],
    iterations: int,
    loops: Sequence[LoopConstraint] = (),
    anchor: Mapping[int, gtsam.Pose3] | None = None,
    observe: LoopObserver | None = None,
) -> tuple[dict[int, gtsam.Pose3], SmoothingReport]:
    """Each segment's keyframe poses (by keyframe number) after smoothing it whole, with the
    ``loops`` inside it as factors (see the module); the report says how it went. ``anchor``:
    keyframe poses a loop closer's pose graph found, in its frame: a later segment that shares
    no keyframe with an earlier one (a re-initialisation, which only the pose graph joined) is
    turned about the vertical and shifted onto them, and a segment whose smoothing fails takes
    them. ``observe``: see :func:`_with_loops`."""
    poses: dict[int, gtsam.Pose3] = {}
    anchor = anchor or {}
    failed, kfs, before, after, why = 0, 0, 0.0, 0.0, []
    used: set[tuple[int, int]] = set()
    observed = 0
    for seg in segments:
        seg, mine_loops, n_obs = _with_loops(seg, loops, observe)
        try:
            est, e0, e1 = _smooth(seg, iterations)
            if not np.isfinite(e1) or e1 > e0:
                raise VioError(f"the smoothing did not lower the error ({e0:.4g} to {e1:.4g})")
        except (*GTSAM_ERRORS, VioError) as exc:
            failed += 1
            why.append(next((ln for ln in str(exc).splitlines() if ln.strip()), "GTSAM failed"))
            held = _keyframe_poses(seg.values)
            poses.update({k: anchor[k] for k in held if k in anchor and k not in poses})
            continue
        mine = _keyframe_poses(est)
        shared = sorted(set(mine) & set(poses))
        common = sorted(set(mine) & set(anchor))
        if shared:  # a restart in place: moved onto the earlier segment where they meet
            fix = _fit_yaw_and_position([poses[shared[0]]], [mine[shared[0]]])
            mine = {j: fix.compose(p) for j, p in mine.items()}
        elif poses and common:  # a new start the pose graph joined: onto its poses
            fix = _fit_yaw_and_position([anchor[k] for k in common], [mine[k] for k in common])
            mine = {j: fix.compose(p) for j, p in mine.items()}
        poses.update(mine)
        kfs += len(mine)
        before, after = before + e0, after + e1
        used.update(mine_loops)
        observed += n_obs
    report = SmoothingReport(
        segments=len(segments) - failed, failed=failed, keyframes=kfs,
        error_before=before, error_after=after, failures=tuple(why),
        loops=len(used), loops_unused=len({(lp.old, lp.new) for lp in loops} - used),
        loops_observed=observed,
    )  # fmt: skip
    return poses, report


def _fit_yaw_and_position(
    targets: Sequence[gtsam.Pose3], poses: Sequence[gtsam.Pose3]
) -> gtsam.Pose3:
    """The turn about the vertical (the mean of the headings' differences) and the shift (the
    mean of the positions' after the turn) that put ``poses`` onto ``targets`` (roll and pitch
    are left alone: gravity fixes them in both)."""
    d = np.array(
        [t.rotation().yaw() - p.rotation().yaw() for t, p in zip(targets, poses, strict=True)]
    )
    yaw = float(np.arctan2(np.sin(d).mean(), np.cos(d).mean()))
    R = gtsam.Rot3.Yaw(yaw)
    q = np.array([np.asarray(t.translation()) for t in targets])
    p = np.array([R.matrix() @ np.asarray(x.translation()) for x in poses])
    return gtsam.Pose3(R, (q - p).mean(axis=0))


def _smooth(seg: GraphHistory, iterations: int) -> tuple[gtsam.Values, float, float]:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iterations)
    params.setRelativeErrorTol(1e-5)
    params.setlambdaUpperBound(1e7)
    e0 = float(seg.factors.error(seg.values))
    est = gtsam.LevenbergMarquardtOptimizer(seg.factors, seg.values, params).optimize()
    return est, e0, float(seg.factors.error(est))


def _keyframe_poses(values: gtsam.Values) -> dict[int, gtsam.Pose3]:
    x = ord("x")
    out = {}
    for key in values.keys():  # noqa: SIM118 (Values is not iterable)
        s = gtsam.Symbol(key)
        if s.chr() == x:
            out[int(s.index())] = values.atPose3(key)
    return out


@dataclass(slots=True)
class ImuLog:
    """Every IMU reading the odometry accepted, in time order (about 150 bytes each: 30
    minutes at 200 Hz hold 54 MB), for the final smoothing's preintegration."""

    _t: list[int] = field(default_factory=list)
    _samples: list[ImuSample] = field(default_factory=list)
    #: the preintegration's parameters in use from each time on (the noise measured then)
    _params_t: list[int] = field(default_factory=list)
    _params: list[gtsam.PreintegrationCombinedParams] = field(default_factory=list)

    def use_params(self, t_ns: int, params: gtsam.PreintegrationCombinedParams) -> None:
        """The odometry preintegrates with ``params`` from ``t_ns`` on."""
        self._params_t.append(int(t_ns))
        self._params.append(params)

    def params_at(self, t_ns: int) -> gtsam.PreintegrationCombinedParams | None:
        """The parameters in use at ``t_ns`` (the first ones before any change)."""
        if not self._params:
            return None
        return self._params[max(bisect.bisect_right(self._params_t, t_ns) - 1, 0)]

    def push(self, sample: ImuSample) -> None:
        if self._t and sample.t_ns <= self._t[-1]:
            return
        self._t.append(int(sample.t_ns))
        self._samples.append(sample)

    def covering(self, t0_ns: int, t1_ns: int) -> list[ImuSample]:
        """The readings a span from ``t0_ns`` to ``t1_ns`` integrates (the one at or before
        ``t0_ns`` first, the first after ``t1_ns`` last)."""
        i = max(bisect.bisect_right(self._t, t0_ns) - 1, 0)
        j = bisect.bisect_left(self._t, t1_ns, lo=i)
        return self._samples[i : j + 1]


def _inflated(
    p: gtsam.PreintegrationCombinedParams, accel_inflation: float
) -> gtsam.PreintegrationCombinedParams:
    """A copy of ``p`` with the accelerometer's noise density times ``accel_inflation``."""
    q = gtsam.PreintegrationCombinedParams.MakeSharedU(float(-np.asarray(p.n_gravity)[2]))
    q.setGyroscopeCovariance(p.getGyroscopeCovariance())
    q.setAccelerometerCovariance(p.getAccelerometerCovariance() * float(accel_inflation) ** 2)
    q.setBiasOmegaCovariance(p.getBiasOmegaCovariance())
    q.setBiasAccCovariance(p.getBiasAccCovariance())
    q.setIntegrationCovariance(p.getIntegrationCovariance())
    return q


def reweighed(
    seg: GraphHistory,
    times: dict[int, int],
    log: ImuLog,
    accel_inflation: float = 1.0,
    *,
    hold_ns: int = 0,
) -> tuple[GraphHistory, int]:
    """``seg`` with each IMU factor between keyframes whose times ``times`` has (keyframe
    number -> ns) preintegrated again from ``log`` with the parameters in use when it was
    made (the noise the window measured then), the accelerometer's noise times
    ``accel_inflation``, at its own bias; how many. A factor the log does not cover is kept
    as it was."""
    x = ord("x")
    out = gtsam.NonlinearFactorGraph()
    done = 0
    made: dict[int, gtsam.PreintegrationCombinedParams] = {}
    for i in range(seg.factors.size()):
        f = seg.factors.at(i)
        if isinstance(f, gtsam.CombinedImuFactor):
            keys = list(f.keys())
            a, b = gtsam.Symbol(keys[0]), gtsam.Symbol(keys[2])
            t0, t1 = times.get(int(a.index())), times.get(int(b.index()))
            if a.chr() == x and b.chr() == x and t0 is not None and t1 is not None:
                bias, p = f.preintegratedMeasurements().biasHat(), log.params_at(t1)
                pim = None
                if p is not None:
                    params = made.setdefault(id(p), _inflated(p, accel_inflation))
                    try:
                        pim = preintegrate(
                            params, log.covering(t0, t1), t0, t1, bias, hold_ns=hold_ns
                        )
                    except VioError:
                        pim = None
                if pim is not None:
                    f = gtsam.CombinedImuFactor(
                        keys[0], keys[1], keys[2], keys[3], keys[4], keys[5], pim
                    )
                    done += 1
        out.add(f)
    return GraphHistory(out, seg.values), done


@dataclass(slots=True)
class FrameTrail:
    """Each tracked frame's pose relative to its reference keyframe (the window's newest when
    the frame was tracked) and each keyframe's last pose: what the final trajectory is made
    of (48 bytes of pose a frame, 56 a keyframe: a 30-minute run at 20 Hz holds 2 MB)."""

    _t_ns: list[int] = field(default_factory=list)
    _ref: list[int] = field(default_factory=list)
    _rel: list[FloatArray] = field(default_factory=list)  # T_K_B as 3x4
    keyframe_poses: dict[int, gtsam.Pose3] = field(default_factory=dict)

    def frame(self, t_ns: int, k: int, T_W_K: gtsam.Pose3, T_W_B: gtsam.Pose3) -> None:
        """A tracked frame at ``t_ns`` whose reference keyframe ``k`` was at ``T_W_K``."""
        if self._t_ns and t_ns <= self._t_ns[-1]:
            return  # (a keyframe's own state after its frame's: the same instant)
        self._t_ns.append(int(t_ns))
        self._ref.append(int(k))
        self._rel.append(np.asarray(T_W_K.between(T_W_B).matrix()[:3], np.float64))
        self.keyframe_poses.setdefault(int(k), T_W_K)

    def __len__(self) -> int:
        return len(self._t_ns)

    def keyframe(self, k: int, T_W_K: gtsam.Pose3) -> None:
        """Keyframe ``k``'s latest pose (the window's, when it leaves)."""
        self.keyframe_poses[int(k)] = T_W_K

    def trajectory(self, poses: dict[int, gtsam.Pose3] | None = None) -> Trajectory:
        """Every frame through its reference keyframe's pose in ``poses`` (a smoothing's), or
        its last pose where ``poses`` has none."""
        poses = poses or {}
        n = len(self._t_ns)
        p = np.zeros((n, 3))
        R = np.zeros((n, 3, 3))
        for i, (k, rel) in enumerate(zip(self._ref, self._rel, strict=True)):
            K = poses.get(k) or self.keyframe_poses[k]
            T = K.matrix() @ np.vstack([rel, [0.0, 0.0, 0.0, 1.0]])
            p[i], R[i] = T[:3, 3], T[:3, :3]
        q = Rotation.from_matrix(R).as_quat() if n else np.zeros((0, 4))
        return Trajectory(t_ns=np.array(self._t_ns, np.int64), p_W_B=p, q_W_B_xyzw=q, name="final")
