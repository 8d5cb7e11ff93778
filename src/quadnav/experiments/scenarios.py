"""The built-in scenarios of ``quadnav run``: a name, what it shows, and its overrides on the
:class:`~quadnav.experiments.nav.NavScenario` defaults. The command's help and the README
table are made from this registry, so neither can drift from it."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from quadnav.errors import ExperimentError
from quadnav.experiments.nav import NavScenario
from quadnav.io.config import load_config

__all__ = ["NAV_SCENARIOS", "NavBuiltin", "nav_builtin", "nav_builtin_overrides"]


@dataclass(frozen=True, slots=True, kw_only=True)
class NavBuiltin:
    name: str
    description: str
    overrides: tuple[str, ...] = ()


_OUTDOOR = (
    "vision.enabled=false",
    "gps.enabled=true",
    "mag.enabled=true",
    "plan.height_m=5",
    "plan.square_m=20",
    "plan.speed_m_s=3",
    "plan.accel_m_s2=2",
    "plan.hold_s=3",
    "plan.yaw=along_track",
)

_VIO = (
    "vision.enabled=false",
    "baro.enabled=false",
    "vio.enabled=true",
    "plan.kind=takeoff_forward",
    "plan.height_m=5",
    "plan.forward_m=5",
    "plan.duration_s=32",
    "sim_dt_s=0.001",
)

# Issue 25: thesis 003's outdoor flight, a VIO and GPS (2 Hz, 1.5 m) with the IMU, no
# barometer or magnetometer; the odometry's frame drifts in position and yaw as indoor_vio's
# VIO did on 2026-12-02 (0.02 m/sqrt(s), 0.004 rad/sqrt(s)) with a 1 % scale error.
_OUTDOOR_VIO = (
    *_OUTDOOR[:1],
    "gps.enabled=true",
    "gps.rate_hz=2",
    "gps.sigma_h_m=1.5",
    "gps.sigma_v_m=2.5",
    "gps.sigma_vel_m_s=0.3",
    "baro.enabled=false",
    *_OUTDOOR[3:],
    "vio.enabled=true",
    "vio.source=odometry",
    "vio.world=yard",
    "vio.drift_m_sqrt_s=0.02",
    "vio.drift_yaw_rad_sqrt_s=0.004",
    "vio.scale_error=0.01",
    # the odometry's position (through its frame's drift) and yaw; its velocity carries its
    # scale error, which the drift states do not model: fused, it pulled the real VIO's flight
    # 0.6 m off (seed 0: 0.65 m against 0.20 m without it) and the NEES to 160
    "vio.fuse=[pos,yaw]",
)

# The filter's rates of the odometry frame's drift (relative mode) where the odometry drifts
# as the shortcut's above (VioSection's defaults are indoor_vio's VIO's, a quarter of these).
_WIDE_DRIFT = ("vio.frame_drift_m_sqrt_s=0.02", "vio.frame_drift_yaw_rad_sqrt_s=0.004")
_OUTDOOR_VIO_RELATIVE = (*_OUTDOOR_VIO, *_WIDE_DRIFT)

# The same on the VIO itself (rendered images), not its shortcut.
_OUTDOOR_VIO_CAMERA = (
    *(
        o
        for o in _OUTDOOR_VIO_RELATIVE
        if not o.startswith(("vio.source", "vio.drift", "vio.scale"))
    ),
    # on realistic sensors the VIO drifts ten times the fixed rates: taken from its own
    # covariance, the median of 5 seeds is 0.725 m against 0.852 m with the fixed rates
    # (2026-12-04 session 20 page)
    "vio.frame_drift_from_covariance=true",
)

_ENTRIES = (
    NavBuiltin(
        name="indoor_vision",
        description="the default: thesis 000's indoor flight over a 6x6 marker field, seen by the "
        "downward camera (rendered, detected, posed; 30 Hz, 250 ms late), two 2 s dropouts",
    ),
    NavBuiltin(
        name="indoor_vision_pose",
        description="the same flight on the pose shortcut (the true pose + 1 cm noise, no "
        "images): 3x faster",
        overrides=("vision.source=pose",),
    ),
    NavBuiltin(
        name="indoor_vision_truth_control",
        description="the default flown on the truth: the estimator's share of the hover error",
        overrides=("closed_loop=false",),
    ),
    NavBuiltin(
        name="indoor_vision_rotated",
        description="PX4's rotated external vision (thesis 000 eqs 3.7-3.8): the marker frame "
        "turned 30 degrees and offset, the heading from the magnetometer",
        overrides=(
            "vision.source=pose",
            "mag.enabled=true",
            "estimator.vision_frame=rotate",
            "vision.frame_yaw_deg=30",
            "vision.frame_offset_m=[1.5,-0.7,0.0]",
        ),
    ),
    NavBuiltin(
        name="indoor_vision_range",
        description="a downward range finder (20 Hz, 2 cm) next to the barometer",
        overrides=("vision.source=pose", "range.enabled=true"),
    ),
    NavBuiltin(
        name="indoor_flow",
        description="no vision: a downward optical-flow sensor (PX4FLOW class, 50 Hz, 15 ms "
        "late), a range finder, the barometer and the IMU; the position is dead-reckoned, the "
        "heading held by a gyro bias levelled at rest",
        overrides=(
            "vision.enabled=false",
            "flow.enabled=true",
            "range.enabled=true",
            "estimator.init_yaw_sigma_unknown_rad=0.05",
            "estimator.gyro_bias_at_rest=true",
        ),
    ),
    NavBuiltin(
        name="indoor_vio",
        description="thesis 003's flight on visual-inertial odometry: its forward camera "
        "(640x480, 20 Hz) rendered in a 9 m high hall and its IMU (200 Hz) into the VIO, whose "
        "odometry (50 ms late) and the IMU feed the EKF (no markers, GPS or barometer); take off "
        "to 5 m, 5 m forward, hover",
        overrides=_VIO,
    ),
    NavBuiltin(
        name="indoor_slam",
        description="the same flight on the stereo SLAM: EuRoC's stereo rig (752x480, 20 Hz, "
        "looking 20 degrees down) rendered in the hall into quadnav's SLAM, whose odometry (50 "
        "ms late, a stated 1 cm and 0.5 degree, its velocity from its last two poses) and the "
        "IMU feed the EKF; its loop closures followed as corrections",
        # (the SLAM's velocity is its last two poses' difference, and its loops jump: at
        # indoor_vio's rates its output was 0.060 m against 0.052 m at these, 5 seeds, session 31)
        overrides=(*_VIO, "vio.odometry=slam", "vio.rig=euroc", *_WIDE_DRIFT),
    ),
    NavBuiltin(
        name="indoor_vio_odometry",
        description="the same flight on the odometry shortcut (the truth + 2 cm, its frame "
        "drifting 5 mm/sqrt(s)): no images, no VIO",
        overrides=(*_VIO, "vio.source=odometry"),
    ),
    NavBuiltin(
        name="outdoor_gps",
        description="a 20 m square at 3 m/s and 5 m on GPS (5 Hz, 200 ms late, 0.5 m), "
        "barometer and magnetometer, facing the direction of travel",
        overrides=_OUTDOOR,
    ),
    NavBuiltin(
        name="outdoor_vio_gps_odometry",
        description="GPS fused with a drifting odometry (issue 25): outdoor_gps's square on GPS "
        "at 2 Hz and 1.5 m and the VIO's shortcut (its frame drifting 0.02 m and 0.004 rad a "
        "sqrt(s), a 1 % scale error) with the IMU; no barometer or magnetometer",
        overrides=_OUTDOOR_VIO_RELATIVE,
    ),
    NavBuiltin(
        name="outdoor_vio_gps",
        description="outdoor_vio_gps_odometry on the VIO itself: the thesis003_sim rig's "
        "forward camera rendered in the yard world into the monocular VIO, its frame's drift "
        "growing as the VIO's own covariance does",
        overrides=_OUTDOOR_VIO_CAMERA,
    ),
    NavBuiltin(
        name="outdoor_vio_gps_realistic",
        description="outdoor_vio_gps on realistic sensors (the IMU at its in-flight noise with "
        "turn-on biases, the VIO given a calibration off as a real one is), started on a "
        "surveyed pad (estimator.start_pose), the VIO frame's drift at 0.05 m/sqrt(s) (the "
        "realistic VIO drifts more than its covariance says), the biases' random walk the IMU's",
        overrides=(
            *_OUTDOOR_VIO_CAMERA,
            "vio.sensors=realistic",
            "estimator.start_pose=[0,0,0,0]",
            # chosen of 0.02, 0.05, 0.07 and 0.1 on seeds 0-4 (0.621, 0.528, 0.542, 0.548 m
            # median), then flown on seeds 5-9: 0.442 m against 0.536 at 0.02 (2026-12-04
            # session 21 page)
            "vio.frame_drift_m_sqrt_s=0.05",
            # the biases' random walk as the IMU's: at the default 3x the filter is unsure of
            # them and its NEES 6-14 for 15; at 1x 12-20, median 13.6 over seeds 0-9, the same
            # error (0.510 and 0.446 m median on seeds 0-4 and 5-9)
            "estimator.bias_rw_inflation=1",
        ),
    ),
    NavBuiltin(
        name="outdoor_vio_gps_outage",
        description="outdoor_vio_gps_odometry with the GPS out from 15 to 45 s: the odometry "
        "carries the position, its drift grows",
        overrides=(*_OUTDOOR_VIO_RELATIVE, "gps.outages_s=[[15,45]]"),
    ),
    NavBuiltin(
        name="outdoor_vio_gps_glitch",
        description="outdoor_vio_gps_odometry with a 20 m GNSS jump from 25 to 28 s: each "
        "glitched fix refused by the gate and counted",
        overrides=(*_OUTDOOR_VIO_RELATIVE, "faults.gps_glitch=[[25,28,20,0]]"),
    ),
    NavBuiltin(
        name="outdoor_vio_gps_reset",
        description="outdoor_vio_gps_odometry whose odometry re-initialises at 30 s (its "
        "position from zero, a new heading, the reset counter up): the filter re-anchors it",
        overrides=(*_OUTDOOR_VIO_RELATIVE, "vio.resets_s=[30]"),
    ),
    NavBuiltin(
        name="outdoor_vio_gps_thesis003",
        description="thesis 003's fusion (robot_localization: the VIO's pose and velocity and "
        "the GPS all taken as absolute fixes of one frame) on outdoor_vio_gps_odometry's "
        "flight and sensors: as the odometry's frame drifts the two disagree",
        overrides=(*_OUTDOOR_VIO, "vio.odometry_mode=absolute", "vio.fuse=[pos,vel,yaw]"),
    ),
    NavBuiltin(
        name="outdoor_gps_2hz",
        description="outdoor_vio_gps_odometry's flight on its GPS (2 Hz, 1.5 m) and IMU alone: "
        "the GPS side of the comparison",
        overrides=tuple(o for o in _OUTDOOR_VIO if not o.startswith("vio.")),
    ),
    NavBuiltin(
        name="fault_gps_glitch",
        description="outdoor_gps with a 20 m GNSS jump from 25 to 28 s: each glitched fix refused "
        "by the gate and counted",
        overrides=(*_OUTDOOR, "faults.gps_glitch=[[25,28,20,0]]"),
    ),
    NavBuiltin(
        name="fault_vision_jump",
        description="the vision frame jumps 1.1 m and 20 degrees with its reset counter bumped: "
        "the filter re-anchors it, the output does not jump",
        overrides=("vision.source=pose", "vision.jumps=[[12.5,20,1.0,-0.5,0.0]]"),
    ),
    NavBuiltin(
        name="fault_bad_samples",
        description="IMU samples with NaN and repeated, vision samples later than the buffer: "
        "each refused and counted",
        overrides=(
            "vision.source=pose",
            "faults.imu_nan_s=[3,6.5,12]",
            "faults.imu_repeat_s=[4,8]",
            "faults.vision_late_s=[[5,0.5],[13,1.0]]",
        ),
    ),
)

#: Every built-in scenario of ``quadnav run`` by name (``planar`` is the planar study).
NAV_SCENARIOS: dict[str, NavBuiltin] = {e.name: e for e in _ENTRIES}


def nav_builtin_overrides(name: str) -> list[str]:
    """The name and overrides of a built-in scenario, for :func:`~quadnav.io.load_config`."""
    if name not in NAV_SCENARIOS:
        raise ExperimentError(
            f"no built-in scenario {name!r}; choose from {', '.join(NAV_SCENARIOS)}"
        )
    return [f"name={name}", *NAV_SCENARIOS[name].overrides]


def nav_builtin(name: str, extra: Iterable[str] = ()) -> NavScenario:
    """A built-in scenario validated, with ``extra`` overrides on top. When ``extra`` turns the
    odometry to the absolute mode, the scenario's own settings of the relative mode (its
    frame's drift rates) are left out: they are its choices for a mode no longer used, not the
    caller's, and validation refuses such settings where the caller gives them."""
    from quadnav.experiments.nav_config import RELATIVE_ONLY_VIO_KEYS
    from quadnav.io.config import apply_override

    extra = list(extra)
    builtin = nav_builtin_overrides(name)
    asked: dict[str, object] = {}
    for e in extra:  # (read as load_config reads them: spaces, quotes, a sweep's JSON)
        if e.partition("=")[0].strip() == "vio.odometry_mode":
            apply_override(asked, e)
    if asked and asked["vio"] == {"odometry_mode": "absolute"}:
        relative_only = tuple(f"vio.{k}=" for k in RELATIVE_ONLY_VIO_KEYS)
        builtin = [o for o in builtin if not o.startswith(relative_only)]
    return load_config(NavScenario, None, [*builtin, *extra])
