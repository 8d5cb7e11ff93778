"""The pose graph off the odometry's critical path.

:class:`BackgroundPoseGraph` takes keyframes (:class:`~quadnav.odometry.KeyframeRecord`, or bare
poses) and loop edges as they come, from the odometry's thread, and returns at once. Its own
thread optimises the whole graph after each new loop (VINS-Mono's ``optimize4DoF`` thread) and
publishes the drift correction: the map-to-odometry transform ``T_M_O`` of the odometry frame of
the newest keyframe optimised (``T_M_O = T_M_B @ T_O_B^-1`` there), and the corrected keyframe
poses. :meth:`~BackgroundPoseGraph.correct` applies it to the odometry's output, and raises the
output's reset counter when the correction jumps, as PX4's external odometry expects.

GTSAM's ``optimize`` holds the GIL for its whole run (``benchmarks/posegraph.py`` measures the
longest pause of a Python loop beside it: as long as the solve), so with ``executor="thread"``
the odometry would stop while the graph solves. The default, ``executor="process"``, solves in
one worker process (spawned: no fork under threads); the thread then only waits on it, without
the GIL. ``executor="inline"`` solves in the caller's thread when a loop is added: a simulation
in simulated time gets each correction at the same step on every run (the threaded executors
publish when the wall clock lets them). Spawning re-imports the caller's main module: a script that makes one must guard its
work with ``if __name__ == "__main__":`` (Python's rule for any spawned process). Bad input is rejected and counted (``rejected``), a failed solve is counted
(``failures``, ``last_error``): nothing stops a long run.
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import threading
from collections import Counter
from collections.abc import Mapping
from concurrent.futures import Executor as _PoolExecutor
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Literal

import numpy as np

from quadnav.errors import PoseGraphError
from quadnav.geometry.rotations import Pose, geodesic_angle_rad
from quadnav.odometry import KeyframeRecord, OdometryState
from quadnav.posegraph.graphs import solve
from quadnav.posegraph.types import (
    COV_SIZE,
    DriftCorrection,
    LoopEdge,
    PoseGraphConfig,
    PoseGraphProblem,
    PoseGraphResult,
)

__all__ = ["BackgroundPoseGraph", "Executor"]

Executor = Literal["process", "thread", "inline"]


def _warm() -> bool:
    """Run in the worker once at start, so that its imports (GTSAM) are paid before a loop."""
    return True


def _new_pool() -> ProcessPoolExecutor:
    """One spawned worker (no fork of a threaded process), warmed up at once."""
    pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
    pool.submit(_warm)
    return pool


class BackgroundPoseGraph:
    """A pose graph optimised in the background; thread-safe. Use as a context manager or call
    :meth:`close`."""

    def __init__(
        self, config: PoseGraphConfig | None = None, *, executor: Executor = "process"
    ) -> None:
        self.config = config or PoseGraphConfig()
        if self.config.kind == "sim3":
            raise PoseGraphError("BackgroundPoseGraph corrects an odometry: kind 4dof or se3")
        self._cv = threading.Condition()
        self._indices: list[int] = []
        self._known: set[int] = set()
        self._t_ns: list[int] = []
        self._reset_counters: list[int] = []
        self._poses: list[Pose] = []
        self._quats: list[np.ndarray] = []
        self._loops: list[LoopEdge] = []
        self._pending = False
        self._busy = False
        self._closed = False
        self._rejected: Counter[str] = Counter()
        self._T_M_O: dict[int, Pose] = {}
        self._T_init: dict[int, Pose] = {}  # each frame's T_M_O until a loop joins it
        self._moved: Counter[int] = Counter()  # how many times set_frame moved each frame
        self._solved_frames: set[int] = set()  # the frames the latest solve's poses hold for
        self._fixed: list[bool] = []
        self._step_var: list[float | None] = []
        self._step_scale = 1.0
        self._latest = DriftCorrection()
        self.optimizations = 0
        self.failures = 0
        self.last_error = ""
        self._pool: _PoolExecutor | None = _new_pool() if executor == "process" else None
        self._inline = executor == "inline"
        self._thread: threading.Thread | None = None
        if not self._inline:
            self._thread = threading.Thread(target=self._run, name="posegraph", daemon=True)
            self._thread.start()

    # ------------------------------------------------------------------ input (any thread)
    def add_keyframe(self, kf: KeyframeRecord) -> bool:
        """Take a finished keyframe of the odometry; False (and counted) if refused."""
        return self.add_pose(kf.index, kf.T_W_B, t_ns=kf.t_ns, reset_counter=kf.reset_counter)

    def start_frame(self, reset_counter: int, T_M_O: Pose) -> None:
        """Odometry frame ``reset_counter`` is taken to be at ``T_M_O`` in the map until a loop
        joins it (its first keyframe is held there): the correction of the frame before it, when
        the odometry went on in the same frame after a gap. Before its first keyframe only."""
        with self._cv:
            if reset_counter not in self._reset_counters:
                self._T_init[reset_counter] = T_M_O

    def set_frame(self, reset_counter: int, T_M_O: Pose) -> None:
        """Odometry frame ``reset_counter``, not yet joined to the map by a loop, is at
        ``T_M_O`` (a relocalization found it): its keyframes move there, its output at once."""
        with self._cv:
            self._T_init[reset_counter] = T_M_O
            self._T_M_O[reset_counter] = T_M_O
            self._moved[reset_counter] += 1

    def add_pose(
        self, index: int, T_O_B: Pose, *, t_ns: int = 0, reset_counter: int = 0,
        fixed: bool = False, step_var: float | None = None,
    ) -> bool:  # fmt: skip
        """Take keyframe ``index`` at odometry pose ``T_O_B`` (``fixed``: held there, a loaded
        map's; ``step_var``: the growth of the odometry's position variance since its keyframe
        before, m^2 an axis, see :class:`PoseGraphConfig`); refused and counted: a non-finite
        pose (``nonfinite_pose``), an index not above the last (``index_order``)."""
        with self._cv:
            q = T_O_B.R_A_B.as_quat()
            if not np.isfinite(q).all():
                self._rejected["nonfinite_pose"] += 1
                return False
            if step_var is not None and not (math.isfinite(step_var) and step_var >= 0.0):
                step_var = 0.0  # a growth the odometry cannot have: the config's sigma alone
            if self._indices and index <= self._indices[-1]:
                self._rejected["index_order"] += 1
                return False
            self._indices.append(int(index))
            self._known.add(int(index))
            self._t_ns.append(int(t_ns))
            self._reset_counters.append(int(reset_counter))
            self._poses.append(T_O_B)
            self._quats.append(q)
            self._fixed.append(bool(fixed))
            self._step_var.append(None if step_var is None else float(step_var))
            return True

    def scale_steps(self, factor: float) -> None:
        """From the next solve on, every keyframe's ``step_var`` is taken ``factor`` times (a
        scale the loops found for the odometry's stated steps); refused: not finite and
        positive."""
        if not (math.isfinite(factor) and factor > 0.0):
            raise PoseGraphError(f"a step scale must be finite and positive, got {factor}")
        with self._cv:
            self._step_scale = float(factor)

    def add_loop(self, edge: LoopEdge) -> bool:
        """Take a verified loop and start an optimisation; refused and counted: a keyframe the
        graph does not have (``unknown_keyframe``), a covariance of another size than the
        graph's (``covariance_size``)."""
        with self._cv:
            if edge.old not in self._known or edge.new not in self._known:
                self._rejected["unknown_keyframe"] += 1
                return False
            n = COV_SIZE[self.config.kind]
            if edge.cov is not None and edge.cov.shape != (n, n):
                self._rejected["covariance_size"] += 1
                return False
            self._loops.append(edge)
            self._pending = True
            self._cv.notify_all()
        if self._inline:
            self._step()
        return True

    # ------------------------------------------------------------------ output (any thread)
    @property
    def rejected(self) -> Mapping[str, int]:
        with self._cv:
            return dict(self._rejected)

    def correction(self) -> DriftCorrection:
        """The latest published correction."""
        with self._cv:
            return self._latest

    def T_M_O(self, reset_counter: int = 0) -> Pose:
        """The map-to-odometry transform of odometry frame ``reset_counter`` (identity until a
        loop reaches it)."""
        with self._cv:
            return self._frame_T(reset_counter)

    def _frame_T(self, reset_counter: int) -> Pose:
        got = self._T_M_O.get(reset_counter)
        return got if got is not None else self._T_init.get(reset_counter, Pose.identity())

    def correct(self, state: OdometryState) -> OdometryState:
        """The odometry's state in the map: pose ``T_M_O @ T_O_B``, velocity turned with it (the
        body-frame covariance is unchanged), reset counter the odometry's plus the jumps."""
        with self._cv:
            T = self._frame_T(state.reset_counter)
            jumps = self._latest.reset_counter
        return dataclasses.replace(
            state,
            T_W_B=T @ state.T_W_B,
            v_W_B=T.R_A_B.apply(state.v_W_B),
            reset_counter=state.reset_counter + jumps,
        )

    def loops(self) -> tuple[LoopEdge, ...]:
        """The loop edges taken so far."""
        with self._cv:
            return tuple(self._loops)

    def pose_of(self, index: int) -> Pose | None:
        """Keyframe ``index``'s corrected pose (as :meth:`keyframe_poses`), or None."""
        with self._cv:
            n = int(np.searchsorted(self._indices, index))
            if n == len(self._indices) or self._indices[n] != index:
                return None
            rc = self._reset_counters[n]
            res = self._latest.result
            if res is not None and rc in self._solved_frames:
                m = int(np.searchsorted(res.indices, index))
                if m < len(res.indices) and res.indices[m] == index:
                    return res.poses[m]
            return self._frame_T(rc) @ self._poses[n]

    def keyframe_poses(self) -> dict[int, Pose]:
        """Every keyframe's corrected pose: the optimised ones as solved, the later ones (and
        those of a frame moved since) through their frame's ``T_M_O``."""
        with self._cv:
            res = self._latest.result
            solved = {} if res is None else dict(zip(res.indices.tolist(), res.poses, strict=True))
            out = {}
            for k, rc, p in zip(self._indices, self._reset_counters, self._poses, strict=True):
                got = solved.get(k) if rc in self._solved_frames else None
                out[k] = got if got is not None else self._frame_T(rc) @ p
            return out

    def wait(self, timeout_s: float | None = None) -> bool:
        """Block until no optimisation is pending or running; False on timeout."""
        with self._cv:
            return self._cv.wait_for(lambda: not (self._pending or self._busy), timeout_s)

    def close(self) -> None:
        """Stop the thread (after the solve under way) and the worker process."""
        with self._cv:
            self._closed = True
            self._cv.notify_all()
        if self._thread is not None:
            self._thread.join()
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> BackgroundPoseGraph:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    # ------------------------------------------------------------------ the optimiser's thread
    def _snapshot(self) -> tuple[PoseGraphProblem, int, dict[int, int]]:
        """The graph as it stands (its inputs checked as they came): arrays, under the lock."""
        start = [
            p if fixed or rc not in self._T_init else self._T_init[rc] @ p
            for p, rc, fixed in zip(self._poses, self._reset_counters, self._fixed, strict=True)
        ]
        problem = PoseGraphProblem(
            indices=np.array(self._indices, np.int64),
            reset_counters=np.array(self._reset_counters, np.int64),
            positions=np.array([p.p_A_B for p in start], np.float64),
            quats_xyzw=np.array([p.R_A_B.as_quat() for p in start], np.float64),
            loops=tuple(self._loops),
            config=self.config,
            fixed=np.array(self._fixed, bool) if any(self._fixed) else None,
            step_var=(
                None if all(v is None for v in self._step_var)
                else np.array([v or 0.0 for v in self._step_var], np.float64) * self._step_scale
            ),
        )  # fmt: skip
        return problem, len(self._indices), dict(self._moved)

    def _run(self) -> None:
        while True:
            with self._cv:
                self._cv.wait_for(lambda: self._pending or self._closed)
                if self._closed:
                    return
            self._step()

    def _step(self) -> None:
        """One solve of the graph as it stands, published (a failure counted)."""
        with self._cv:
            self._pending, self._busy = False, True
            try:
                problem, n, moved = self._snapshot()
            except Exception as exc:  # a bad snapshot must not end the thread
                self._fail(exc)
                return
        try:
            result = (
                solve(problem) if self._pool is None else self._pool.submit(solve, problem).result()
            )
        except Exception as exc:  # counted; the run goes on without this solve
            with self._cv:
                self._fail(exc)
                if isinstance(exc, BrokenProcessPool):  # the worker died: a new one
                    self._pool = _new_pool()
            return
        with self._cv:
            self._publish(result, n, moved)
            self._busy = False
            self._cv.notify_all()

    def _fail(self, exc: Exception) -> None:
        self.failures += 1
        self.last_error = f"{type(exc).__name__}: {exc}"
        self._busy = False
        self._cv.notify_all()

    def _publish(self, result: PoseGraphResult, n: int, moved: dict[int, int]) -> None:
        """Take a solve of the first ``n`` keyframes: ``T_M_O`` of each odometry frame from its
        newest keyframe solved (not of a frame :meth:`set_frame` moved while it solved: the
        solve saw it where it was), and a jump of the newest keyframe against the previous
        correction raising the reset counter."""
        rcs = self._reset_counters[:n]
        newest, rc = n - 1, rcs[n - 1]
        old = self._frame_T(rc) @ self._poses[newest]  # the output until now
        self._solved_frames = set()
        for frame in set(rcs):
            if self._moved[frame] != moved.get(frame, 0):
                continue
            self._solved_frames.add(frame)
            last = max(m for m in range(n) if rcs[m] == frame)
            self._T_M_O[frame] = result.poses[last] @ self._poses[last].inverse()
        new = self._frame_T(rc) @ self._poses[newest]
        if rc in self._solved_frames:
            new = result.poses[newest]
        jump_m = float(np.linalg.norm(new.p_A_B - old.p_A_B))
        jump_rad = float(geodesic_angle_rad(old.R_A_B, new.R_A_B))
        jumped = jump_m > self.config.reset_jump_m or jump_rad > self.config.reset_jump_rad
        self.optimizations += 1
        self._latest = DriftCorrection(
            t_ns=self._t_ns[newest],
            keyframe_index=self._indices[newest],
            odometry_reset_counter=rc,
            T_M_O=self._T_M_O[rc],
            reset_counter=self._latest.reset_counter + int(jumped),
            jump_m=jump_m,
            jump_rad=jump_rad,
            result=result,
        )
