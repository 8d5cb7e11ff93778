"""Visual-inertial odometry in the main job's closed loop (``quadnav run indoor_vio``, thesis 003
section 6.3: take off to 5 m and fly forward on VINS odometry).

The ``vio`` channel of :mod:`quadnav.experiments.nav_channels` is built here. With
``vio.source=camera`` it is a companion computer: the rig's IMU (in the rig's body, at its rate)
and its camera, rendered at the camera's rate in a 3-D world (:mod:`quadnav.sim.scene`,
:class:`~quadnav.sim.render.Renderer`), go into the :class:`~quadnav.vio.VioEstimator`; each
optimised state, converted to the vehicle's body (:func:`vehicle_odometry`), is an
:class:`~quadnav.messages.OdometrySample` (PX4's ODOMETRY) for the navigation EKF, delivered
``vio.delay_s`` later (the processing latency), and handed to an optional sink (``--mavlink``).
With ``vio.source=odometry`` it is the shortcut: the true pose and velocity plus noise, the
frame's origin drifting as a random walk.

The loop itself is :func:`quadnav.experiments.nav.run_nav`; what the VIO did (its own
estimate, events, frames, timing) comes back as a :class:`VioRecord`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.random import Generator
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import ConfigError, SampleError
from quadnav.estimation.nav_ekf import skew
from quadnav.experiments.nav_config import NavScenario, VioSection
from quadnav.geometry.rotations import (
    Pose,
    quat_xyzw_from_matrix,
    rot_z,
    rotation_matrix_xyzw,
    so3_exp,
)
from quadnav.geometry.trajectory import Trajectory
from quadnav.messages import ImageFrame, ImuSample, OdometrySample, VehicleState
from quadnav.sim.sensors import IntegratingImu, Ticker
from quadnav.units import s_to_ns

if TYPE_CHECKING:  # (the rig, the renderer and the VIO load OpenCV and GTSAM: only when used)
    from quadnav.odometry import KeyframeRecord, OdometryState, VisualOdometry
    from quadnav.rig import Rig
    from quadnav.sim.render import RenderEffects, Renderer
    from quadnav.sim.scene import Scene

__all__ = [
    "OdometryShortcut",
    "OdometrySink",
    "VioCameraSensor",
    "VioRecord",
    "build_vio_sensor",
    "flight_rig",
    "flight_world",
    "planned_path",
    "vehicle_odometry",
    "vio_imu",
    "with_loop_closure",
    "world_around",
]

FloatArray = NDArray[np.float64]
OdometrySink = Callable[[OdometrySample], None]


@dataclass(frozen=True, slots=True, kw_only=True)
class VioRecord:
    """What the VIO did in one flight: its own estimate at each optimised camera frame (the
    rig's body ``B`` in the VIO's world), with its reset counter and the true position of
    ``B`` then (in the flight's world) and its true attitude; its events ``(t_ns, text)``;
    the frames it was given and the states it returned; the odometry refused at the boundary
    (non-finite); its wall time per stage (ms per call)."""

    t_ns: NDArray[np.int64]
    p_W_B: FloatArray
    q_W_B_xyzw: FloatArray
    reset_counter: NDArray[np.int64]
    truth_p_W_B: FloatArray
    truth_q_W_B_xyzw: FloatArray
    events: tuple[tuple[int, str], ...] = ()
    frames: int = 0
    states: int = 0
    rejected_invalid: int = 0
    stage_ms: dict[str, float] = field(default_factory=dict)
    #: with loop closure: its counts (:meth:`quadnav.loop.closer.LoopStats.as_json`), and the
    #: map to save (``vio.save_map``; a :class:`~quadnav.loop.map.LoopMap`)
    loop: dict[str, Any] | None = None
    loop_map: Any = None


_TrackRow = tuple[int, FloatArray, FloatArray, int]  # t_ns, p_W_B, q_W_B_xyzw, reset counter


def _trajectory(rows: list[_TrackRow]) -> Trajectory:
    return Trajectory(
        t_ns=np.array([x[0] for x in rows], dtype=np.int64),
        p_W_B=np.array([x[1] for x in rows]).reshape(-1, 3),
        q_W_B_xyzw=np.array([x[2] for x in rows]).reshape(-1, 4),
    )


def _truth_at(
    track: list[_TrackRow], frames: list[_TrackRow]
) -> list[tuple[FloatArray, FloatArray]]:
    """The true pose at each row of ``track``, interpolated between the camera frames' true
    poses: a VIO that estimates its camera's time offset stamps its states at the frame's time
    plus that offset, not at a frame time (looked up by the frame time, every state after the
    offset's first estimate had no truth, and the VIO's error was measured on the hover before
    it alone). NaN outside the frames' span."""
    nan = (np.full(3, np.nan), np.full(4, np.nan))
    if len(frames) < 2:
        exact = {row[0]: (row[1], row[2]) for row in frames}
        return [exact.get(row[0], nan) for row in track]
    truth = _trajectory(sorted(frames, key=lambda row: row[0]))
    t = np.array([row[0] for row in track], dtype=np.int64)
    inside = (t >= truth.t_ns[0]) & (t <= truth.t_ns[-1])
    at = truth.interpolate(t[inside])
    out = [nan] * len(track)
    for k, i in enumerate(np.flatnonzero(inside)):
        out[i] = (at.p_W_B[k], at.q_W_B_xyzw[k])
    return out


def _record(
    track: list[_TrackRow], truth: list[tuple[FloatArray, FloatArray]], **counts: Any
) -> VioRecord:
    """``truth``: the true position and attitude (quaternion) at each row of ``track``."""
    return VioRecord(
        truth_p_W_B=np.array([p for p, _ in truth], dtype=np.float64).reshape(-1, 3),
        truth_q_W_B_xyzw=np.array([q for _, q in truth], dtype=np.float64).reshape(-1, 4),
        t_ns=np.array([x[0] for x in track], dtype=np.int64),
        p_W_B=np.array([x[1] for x in track]).reshape(-1, 3),
        q_W_B_xyzw=np.array([x[2] for x in track]).reshape(-1, 4),
        reset_counter=np.array([x[3] for x in track], dtype=np.int64),
        **counts,
    )


def vehicle_odometry(
    state: OdometryState, T_V_B: Pose, w_B_rad_s: FloatArray, *, source: str = "vio"
) -> OdometrySample:
    """A VIO state of the rig's body ``B`` as odometry of the vehicle ``V`` (FLU, its centre):
    ``T_W_V = T_W_B T_V_B^-1``, the velocity of V's origin ``v_B - R_W_V (w_V x p_V_B)``, the
    position covariance moved with the lever arm (``dp_V = [R_W_V p_V_B]x dtheta``). A state
    holding a non-finite value is a :class:`~quadnav.errors.SampleError`."""
    odo = state.odometry(source=source)
    R_V_B, p_V_B = T_V_B.R_A_B, T_V_B.p_A_B
    R_W_V = Rotation.from_quat(odo.q_W_B_xyzw) * R_V_B.inv()
    r_W = R_W_V.apply(p_V_B)
    w_V = R_V_B.apply(np.asarray(w_B_rad_s, dtype=np.float64))
    J = np.eye(6)
    J[0:3, 3:6] = skew(r_W)
    return OdometrySample(
        t_ns=odo.t_ns,
        p_W_B=odo.p_W_B - r_W,
        q_W_B_xyzw=R_W_V.as_quat(),
        v_W_B=odo.v_W_B - R_W_V.apply(np.cross(w_V, p_V_B)),
        cov_pose=J @ odo.cov_pose @ J.T,
        cov_v=odo.cov_v,
        reset_counter=odo.reset_counter,
        quality=odo.quality,
        source=source,
    )


def vio_imu(
    rig: Rig, bias_rng: Generator, gravity_m_s2: float, *, realistic: bool = False
) -> IntegratingImu:
    """The rig's IMU on the vehicle, mounted at the rig's body origin (read in the vehicle's
    axes; :class:`VioCameraSensor` turns them into the rig's). Ideal: its stated noise
    densities at its rate and turn-on biases drawn from ``bias_rng`` at a tenth of the random
    walk's 100-s spread. ``realistic`` (``vio.sensors``, as ``quadnav dataset make``'s profile):
    the noise it shows in flight (the rotors' vibration: the rig's ``flight_noise``) and
    turn-on biases drawn from the rig's stated spread."""
    assert rig.imu is not None  # (the rigs vio.rig offers all have one)
    n, f = rig.imu.noise, rig.imu.rate_hz
    if realistic:
        n = (rig.imu.flight_noise or n).draw_turn_on_biases(bias_rng)
        bg0, ba0 = n.gyro_bias0_rad_s, n.accel_bias0_m_s2
    else:
        bg0 = tuple(10 * n.gyro_random_walk * bias_rng.standard_normal(3))
        ba0 = tuple(10 * n.accel_random_walk * bias_rng.standard_normal(3))
    return IntegratingImu(
        period_ns=s_to_ns(1.0 / f),
        gyro_sigma_rad_s=n.gyro_noise_density * math.sqrt(f),
        accel_sigma_m_s2=n.accel_noise_density * math.sqrt(f),
        gyro_bias_rw_rad_s_sqrt_s=n.gyro_random_walk,
        accel_bias_rw_m_s2_sqrt_s=n.accel_random_walk,
        gyro_bias0_rad_s=bg0,
        accel_bias0_m_s2=ba0,
        gravity_m_s2=gravity_m_s2,
        lever_arm_m=tuple(rig.T_V_B.p_A_B),
    )


def planned_path(sc: NavScenario) -> FloatArray:
    """The route the flight's plan flies (N, 3, world ENU): take-off, then ``forward_m`` ahead
    (``takeoff_forward``), or the square's waypoints, every lap, and the landing."""
    if sc.plan.kind == "takeoff_forward":
        h, fwd = sc.plan.height_m, sc.plan.forward_m
        return np.array([[0.0, 0.0, 0.0], [0.0, 0.0, h], [fwd, 0.0, h]])
    return np.asarray(sc.waypoints().points_m, dtype=np.float64)


def flight_world(sc: NavScenario) -> Scene:
    """The world of the flight: built around the route its plan flies (obstacles kept a metre
    from it) and a margin of a metre about it. (Until 2026-12-04 it was built around the
    take-off-and-forward route whatever the plan: ``outdoor_vio_gps``'s 20 m square flew
    through the yard's buildings.)"""
    return world_around(planned_path(sc), sc.vio.world, sc.vio.world_seed)


def world_around(path_W: FloatArray, world: str, seed: int) -> Scene:
    """The built-in ``world`` (:data:`quadnav.sim.scene.WORLDS`) around a flight path (N, 3):
    its box with a metre's margin below, beside and ahead of it and half a metre above,
    obstacles a metre clear of the path."""
    from quadnav.sim.scene import WORLDS, WorldPlan

    lo, hi = path_W.min(axis=0), path_W.max(axis=0)
    plan = WorldPlan(
        flight_min_m=(lo[0] - 1.0, lo[1] - 1.0, min(0.0, lo[2])),
        flight_max_m=(hi[0] + 1.0, hi[1] + 1.0, hi[2] + 0.5),
        seed=seed,
        path_W=path_W,
        clearance_m=1.0,
    )
    return WORLDS[world](plan)


def _constant(image: NDArray[np.uint8]) -> Callable[[], NDArray[np.uint8]]:
    """An image's loader (bound now: a stereo odometry loads the left image at its partner)."""
    return lambda: image


def _renderers(first: Renderer, rig: Rig, names: tuple[str, ...]) -> dict[str, Renderer]:
    """A renderer per camera, each through its own lens (a stereo pair's intrinsics differ:
    EuRoC's principal points are 13 px apart), sharing ``first``'s scene; ``first`` renders
    the first camera."""
    from quadnav.sim.render import Renderer

    out = {names[0]: first}
    for n in names[1:]:
        out[n] = Renderer(first.scene, rig.camera(n).camera)
    return out


class VioCameraSensor:
    """A companion computer with a camera-IMU rig: IMU samples in the rig's body at the IMU's
    rate and images rendered at the camera's rate into a :class:`VisualOdometry`; each state it
    returns at an image is the vehicle's :class:`OdometrySample` (and goes to ``sink``).
    The cameras the odometry uses (``vio.cameras``: a stereo SLAM both of a rig's) are rendered
    at each frame time in turn, each through its own lens, at the first one's rate or
    ``rate_hz`` (an odometry that keeps up with fewer frames than the camera gives), the first
    at ``first_ns`` (one period in by default); without ``imu`` no IMU sample is given (an
    odometry that uses none)."""

    def __init__(
        self,
        *,
        rig: Rig,
        vio: VisualOdometry,
        renderer: Renderer,
        imu: IntegratingImu | None,
        image_rng: Generator,
        effects: RenderEffects,
        rate_hz: float | None = None,
        first_ns: int | None = None,
        sink: OdometrySink | None = None,
        save_map: bool = False,
    ) -> None:
        names = tuple(vio.cameras)
        spec = rig.camera(names[0])
        self.vio, self.renderer, self.imu, self.effects = vio, renderer, imu, effects
        self.T_V_B, self.T_V_C = rig.T_V_B, rig.T_V_B @ spec.T_B_C
        self._T_V_Cs = tuple((n, rig.T_V_B @ rig.camera(n).T_B_C) for n in names)
        self._renderers = _renderers(renderer, rig, names)
        self._R_B_V = rig.T_V_B.R_A_B.inv().as_matrix()
        period = s_to_ns(1.0 / (rate_hz or spec.rate_hz))
        self._camera = Ticker(period, first_ns=period if first_ns is None else first_ns)
        self._image_rng, self.sink = image_rng, sink
        self._save_map = save_map
        self._truth_B: dict[int, _TrackRow] = {}  # the rig's true pose at each camera frame
        self._keyframes: list[_TrackRow] = []  # the odometry's keyframes (with loop closure)
        self._w_B = np.zeros(3)
        self._track: list[_TrackRow] = []
        self.frames = self.states = self.rejected_invalid = 0

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> OdometrySample | None:
        s = None if self.imu is None else self.imu.sample(truth, t_ns, rng)
        if s is not None:  # (read in the vehicle's axes at the rig's origin: into the rig's)
            imu_B = ImuSample(
                t_ns=s.t_ns, gyro_rad_s=self._R_B_V @ s.gyro_rad_s, accel_m_s2=self._R_B_V @ s.accel_m_s2
            )  # fmt: skip
            self._w_B = imu_B.gyro_rad_s
            self.vio.push(imu_B)
        if not self._camera.due(t_ns):
            return None
        T_W_V = Pose.from_quat_xyzw(truth.q_W_B_xyzw, truth.p_W_B)
        if self.imu is None:  # (the rate the lever arm needs: the true one)
            self._w_B = self._R_B_V @ truth.w_B
        state = None
        for name, T_V_C in self._T_V_Cs:
            image = self._renderers[name].render(T_W_V @ T_V_C).image
            image = self.effects.apply(image, self._image_rng)
            state = self.vio.push(ImageFrame(t_ns=t_ns, camera=name, load=_constant(image)))
        self.frames += 1
        T_W_B = T_W_V @ self.T_V_B
        self._truth_B[t_ns] = (t_ns, T_W_B.p_A_B, T_W_B.R_A_B.as_quat(), 0)
        self._take_keyframes(self.vio.keyframes())
        if state is None:
            return None
        self.states += 1
        try:
            odo = vehicle_odometry(state, self.T_V_B, self._w_B - state.gyro_bias)
        except SampleError:  # a non-finite state: refused at the boundary, counted
            self.rejected_invalid += 1
            return None
        T = state.T_W_B
        self._track.append((state.t_ns, T.p_A_B, T.R_A_B.as_quat(), state.reset_counter))
        if self.sink is not None:
            self.sink(odo)
        return odo

    def record(self) -> VioRecord:
        loop, loop_map = self._finish_loop()
        return _record(
            self._track,
            _truth_at(self._track, list(self._truth_B.values())),
            events=tuple((e.t_ns, f"{e.kind}: {e.detail}") for e in self.vio.events),
            frames=self.frames,
            states=self.states,
            rejected_invalid=self.rejected_invalid,
            stage_ms=self.vio.timing().per_call_ms(),
            loop=loop,
            loop_map=loop_map,
        )

    def _take_keyframes(self, records: Sequence[KeyframeRecord]) -> None:
        """The flight keeps no map: of the keyframes the odometry publishes only their poses are
        kept, with loop closure, to judge its places against the truth."""
        from quadnav.loop import LoopClosure

        if not isinstance(self.vio, LoopClosure):
            return
        for rec in records:
            T = rec.T_W_B
            self._keyframes.append((rec.t_ns, T.p_A_B, T.R_A_B.as_quat(), rec.reset_counter))

    def _finish_loop(self) -> tuple[dict[str, Any] | None, Any]:
        """With loop closure: the last keyframes into the graph, its counts and its places
        judged against the truth (``evaluation``: precision, recall, the measurements' errors),
        the map to save, and its worker stopped."""
        from quadnav.experiments.odometry_report import loop_evaluation
        from quadnav.loop import LoopClosure

        vio = self.vio
        if not isinstance(vio, LoopClosure):
            return None, None
        try:
            self._keyframes += [
                (r.t_ns, r.T_W_B.p_A_B, r.T_W_B.R_A_B.as_quat(), r.reset_counter)
                for r in vio.keyframes(final=True)
            ]
            the_map = vio.export_map() if self._save_map else None
            evaluation = None
            if self._keyframes and self._truth_B:
                kf, truth = _trajectory(self._keyframes), _trajectory(list(self._truth_B.values()))
                ev = loop_evaluation(vio, kf, truth)
                evaluation = None if ev is None else ev.as_metrics()
        finally:
            vio.close()
        return {**vio.stats.as_json(), "evaluation": evaluation}, the_map


@dataclass
class OdometryShortcut:
    """The VIO's shortcut, a drifting odometry: the vehicle's motion at ``period_ns`` in a frame
    of its own that drifts as a VIO's does, plus white noise of the sigmas, reported with the
    white noise's covariance (what a VIO states of its pose in its own frame).

    The frame starts on the world. Each sample's motion since the last (the truth's) is turned
    by the frame's yaw drift and scaled by ``1 + scale_error`` before it is added, so a yaw
    drift turns only the motion after it, as a VIO's does; the frame's origin drifts as a
    random walk (``drift_m_sqrt_s`` per axis) and its yaw too (``drift_yaw_rad_sqrt_s``). At
    each time of ``resets_ns`` the odometry re-initialises: its position restarts at zero, its
    yaw at a random heading, and its reset counter goes up (PX4's ``ODOMETRY.reset_counter``).
    With the yaw drift, the scale error and the resets at zero it draws the same numbers as the
    pure position drift of before."""

    period_ns: int
    sigma_m: float
    sigma_vel_m_s: float
    sigma_att_rad: float
    drift_m_sqrt_s: float = 0.0
    drift_yaw_rad_sqrt_s: float = 0.0
    scale_error: float = 0.0
    resets_ns: Sequence[int] = ()
    sink: OdometrySink | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.scale_error) and -0.5 < self.scale_error < 0.5):
            raise ConfigError(
                f"the odometry's scale error must lie in (-0.5, 0.5), got {self.scale_error}"
            )
        self._ticker = Ticker(self.period_ns, first_ns=self.period_ns)
        self._p_O: FloatArray | None = None  # the odometry's position in its frame (no noise)
        self._p_W_last = np.zeros(3)
        self._yaw = 0.0  # the frame's yaw drift (rad): R_O_W = Rz(yaw)
        self._resets = sorted(int(t) for t in self.resets_ns)
        self._reset_counter = 0
        self._t_last: int | None = None
        self._track: list[_TrackRow] = []
        self._truth: list[tuple[FloatArray, FloatArray]] = []

    def _drift(self, t_ns: int, truth: VehicleState, rng: Generator) -> FloatArray:
        """Moves the frame on to ``t_ns`` (drift, the motion since the last sample, a reset
        due) and returns ``R_O_W``."""
        if self._p_O is None:
            self._p_O = truth.p_W_B.copy()
        elif self._t_last is not None:
            dt = (t_ns - self._t_last) * 1e-9
            if self.drift_yaw_rad_sqrt_s > 0:
                self._yaw += float(rng.normal(0.0, self.drift_yaw_rad_sqrt_s * math.sqrt(dt)))
            step = truth.p_W_B - self._p_W_last
            if self._yaw != 0.0 or self.scale_error != 0.0:
                step = (1.0 + self.scale_error) * (rot_z(self._yaw) @ step)
            self._p_O = self._p_O + step + rng.normal(0.0, self.drift_m_sqrt_s * math.sqrt(dt), 3)
        while self._resets and self._resets[0] <= t_ns:
            self._resets.pop(0)
            self._reset_counter += 1
            self._p_O = np.zeros(3)
            self._yaw = float(rng.uniform(-math.pi, math.pi))
        self._p_W_last = truth.p_W_B.copy()
        self._t_last = t_ns
        return rot_z(self._yaw)

    def sample(self, truth: VehicleState, t_ns: int, rng: Generator) -> OdometrySample | None:
        if not self._ticker.due(t_ns):
            return None
        R_O_W = self._drift(t_ns, truth, rng)
        assert self._p_O is not None
        R = (
            so3_exp(rng.normal(0.0, self.sigma_att_rad, 3))
            @ R_O_W
            @ rotation_matrix_xyzw(truth.q_W_B_xyzw)
        )
        v_O = (1.0 + self.scale_error) * (R_O_W @ truth.v_W_B)
        odo = OdometrySample(
            t_ns=t_ns,
            p_W_B=self._p_O + rng.normal(0.0, self.sigma_m, 3),
            q_W_B_xyzw=quat_xyzw_from_matrix(R),
            v_W_B=v_O + rng.normal(0.0, self.sigma_vel_m_s, 3),
            cov_pose=np.diag([self.sigma_m**2] * 3 + [self.sigma_att_rad**2] * 3),
            cov_v=np.eye(3) * self.sigma_vel_m_s**2,
            reset_counter=self._reset_counter,
        )
        self._track.append((t_ns, odo.p_W_B, odo.q_W_B_xyzw, self._reset_counter))
        self._truth.append((truth.p_W_B, truth.q_W_B_xyzw))
        if self.sink is not None:
            self.sink(odo)
        return odo

    def record(self) -> VioRecord:
        return _record(self._track, self._truth, states=len(self._track))


def build_vio_sensor(
    sc: NavScenario,
    rng: Generator,
    bias_rng: Generator,
    gravity_m_s2: float,
    sink: OdometrySink | None,
) -> VioCameraSensor | OdometryShortcut:
    """The ``vio`` section's sensor: the rendered cameras and the odometry (``vio.odometry``:
    the VIO or the SLAM), or the shortcut."""
    v = sc.vio
    if v.source == "odometry":
        return OdometryShortcut(
            period_ns=s_to_ns(1.0 / v.rate_hz),
            sigma_m=v.sigma_m,
            sigma_vel_m_s=v.sigma_vel_m_s,
            sigma_att_rad=v.yaw_sigma_rad,
            drift_m_sqrt_s=v.drift_m_sqrt_s,
            drift_yaw_rad_sqrt_s=v.drift_yaw_rad_sqrt_s,
            scale_error=v.scale_error,
            resets_ns=[s_to_ns(t) for t in v.resets_s],
            sink=sink,
        )
    # (OpenCV, the renderer, GTSAM and the front end only when flying on rendered images)
    from quadnav.sim.render import RenderEffects, Renderer

    rig = flight_rig(v)
    camera = rig.cameras[0]
    realistic = v.sensors == "realistic"
    return VioCameraSensor(
        rig=rig,
        vio=_odometry(v, stated_rig(v, rig, rng) if realistic else rig),
        save_map=v.save_map,
        renderer=Renderer(flight_world(sc), camera.camera),
        imu=vio_imu(rig, bias_rng, gravity_m_s2, realistic=realistic),
        image_rng=np.random.default_rng(int(rng.integers(2**31))),
        effects=RenderEffects(read_noise_sigma=v.image_noise),
        rate_hz=v.camera_rate_hz,
        sink=sink,
    )


def stated_rig(v: VioSection, rig: Rig, rng: Generator) -> Rig:
    """``rig`` as its calibration states it to the odometry (``vio.sensors=realistic``): its
    cameras' extrinsics and intrinsics off as ``quadnav dataset make``'s realistic profile
    draws them (:func:`~quadnav.experiments.datasets.miscalibrated_cameras`, its default
    sizes), the images rendered through the true ones."""
    from dataclasses import replace

    from quadnav.experiments.datasets import SequenceSpec, miscalibrated_cameras

    spec = SequenceSpec(world=v.world, rig=v.rig, seed=int(rng.integers(1_000_000)))
    return replace(rig, cameras=miscalibrated_cameras(spec, rig.cameras))


def flight_rig(v: VioSection) -> Rig:
    """The rig of ``vio.rig``, its camera at least as fast as ``vio.camera_rate_hz`` (a
    :class:`~quadnav.errors.ConfigError` naming it otherwise: checked before flying)."""
    from quadnav.rig import rig_named

    rig = rig_named(v.rig)
    rate = rig.cameras[0].rate_hz
    if v.camera_rate_hz is not None and v.camera_rate_hz > rate:
        raise ConfigError(
            f"vio.camera_rate_hz {v.camera_rate_hz:g} is faster than vio.rig {v.rig}'s camera "
            f"({rate:g} Hz)"
        )
    return rig


def _odometry(v: VioSection, rig: Rig) -> VisualOdometry:
    """The odometry of ``vio.odometry`` on ``rig``: the VIO (behind loop closure if asked) or
    the stereo SLAM (which takes the IMU's samples and uses none)."""
    if v.odometry == "slam":
        from quadnav.slam.odometry import SlamOdometry

        return SlamOdometry(rig)
    from quadnav.vio.estimator import VioEstimator

    vio: VisualOdometry = VioEstimator(rig, v.estimator_config())
    return with_loop_closure(vio, rig, v.load_map) if v.loop_closure else vio


def with_loop_closure(vio: VisualOdometry, rig: Rig, load_map: str | None) -> VisualOdometry:
    """The VIO behind loop closure, on the map ``load_map`` (``vio.load_map``) if given. The
    pose graph solves in the flight's own thread (``inline``): a flight in simulated time gets
    each correction at the same step on every run."""
    from pathlib import Path

    from quadnav.errors import LoopError
    from quadnav.io.loop_map import load_loop_map
    from quadnav.loop import LoopClosure, LoopConfig

    loop_map = None if load_map is None else load_loop_map(Path(load_map), option="vio.load_map")
    try:
        return LoopClosure(vio, rig.camera("cam0"), config=LoopConfig(executor="inline"),
                           loop_map=loop_map)  # fmt: skip
    except LoopError as exc:
        raise LoopError(f"vio.load_map {load_map}: {exc}") from None
