"""The visual-inertial odometry's settings (VINS-Mono's names where it has them): the window,
the front end, the landmarks, the static start, the failure thresholds and the time offset."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from quadnav.config_model import ConfigModel
from quadnav.units import GRAVITY_M_S2
from quadnav.vision.tracker_config import TrackerConfig

__all__ = ["VioConfig"]


def _tracker() -> TrackerConfig:
    """VINS-Mono's EuRoC front end: 150 features, 30 px apart, F threshold 1 px; corners
    detected once 20 are missing (VINS: every frame), about half the detections for 144
    features a frame instead of 149. ATE 4-DoF, every frame against once 20 are missing:
    ideal room_medium_60 (60 s) 0.020 and 0.018 m mono, 0.013 and 0.013 m stereo; realistic
    MH_01 seed 0 (40 s) 0.022 and 0.022 m mono, 0.014 and 0.015 m stereo."""
    return TrackerConfig(
        max_features=150, min_distance_px=30.0, ransac_threshold_px=1.0, detect_min_new=20
    )


class VioConfig(ConfigModel):
    """The estimator's settings. Parallax is stated in pixels at ``parallax_focal_px`` (VINS:
    10 px at focal 460) and compared in normalised image coordinates, so it means the same
    angle for any camera."""

    window_keyframes: int = Field(10, ge=4, le=30, description="keyframes in the window")
    tracker: TrackerConfig = Field(default_factory=_tracker, description="KLT front end")

    @field_validator("tracker", mode="before")
    @classmethod
    def _tracker_over_the_vios_defaults(cls, value: object) -> object:
        """A partial ``tracker`` section (``--set tracker.max_features=200``) changes those keys
        of the VIO's own tracker defaults, not of the standalone tracker's (their corner
        detection differs)."""
        if isinstance(value, dict):
            return {**_tracker().model_dump(), **value}
        return value

    # off: on ideal room_medium_60 it keeps more tracks (1.4 fewer a frame lost to the
    # forward-backward check, 1.7 fewer corners to detect), but on realistic MH_01 (seeds 0-2) it
    # took the mono ATE from 0.013/0.013/0.012 to 0.015/0.016/0.013 m
    predict_flow: bool = Field(
        False,
        description="KLT starts each feature where the gyro's rotation since the last frame "
        "moves it (VINS-Fusion, OpenVINS), over tracker.predicted_pyramid_levels: for turns "
        "faster than KLT's pyramid reaches",
    )

    # VINS-Mono uses 10 px (at focal 460); 16 px measured better here on V1_02's motion (40 s:
    # ATE 0.032 against 0.036 m) and on room_medium, with 30 % fewer solves
    keyframe_parallax_px: float = Field(
        16.0, gt=0.0, le=100.0, description="mean parallax to the last keyframe for a new one"
    )
    parallax_focal_px: float = Field(
        460.0, gt=10.0, le=5000.0, description="focal length the parallax is stated at"
    )
    keyframe_min_tracked: int = Field(
        20, ge=1, le=1000, description="fewer features tracked from the last keyframe: keyframe"
    )
    keyframe_max_interval_s: float = Field(
        0.5, gt=0.0, le=10.0, description="longest time between keyframes (at rest too)"
    )
    drop_second_newest: bool = Field(
        False,
        description="a keyframe made by time alone (little parallax) has the previous newest "
        "leave rather than the oldest, so a hover keeps the window's baseline (VINS' "
        "MARGIN_SECOND_NEW); off: the landmarks anchored in it leave too, and in indoor_vio's "
        "hover the VIO lost more than it kept (0.089 m against 0.038 m)",
    )
    drop_at_rest: bool = Field(
        True,
        description="at rest (the IMU and the images still), a keyframe made by time alone has "
        "the previous newest leave rather than the oldest when that one was at rest too: the "
        "window keeps the keyframes and landmarks of the motion before the rest, and with them "
        "the scale (a monocular VIO lost it over EuRoC MH_01's 20 s on the ground: 0.62 m), "
        "the rest's zero-velocity constraints chained across the dropped ones",
    )
    drop_at_rest_max_s: float = Field(
        60.0,
        gt=0.0,
        le=3600.0,
        description="drop_at_rest while the window's oldest keyframe is at most this old: the "
        "IMU is kept back to it (a vehicle parked for an hour would hold an hour of it)",
    )
    # VINS-Mono's EuRoC value (1.5 px at focal 460). The KLT residuals after a solve are 0.36 px
    # (rendered room_medium), but a track's errors are not independent from keyframe to
    # keyframe: with 1 px the pose NEES / 6 on corridor1's motion was 2.2 (3 seeds), 1.6 now
    pixel_sigma_px: float = Field(1.5, gt=0.0, le=20.0, description="feature measurement noise")
    huber_k: float = Field(
        1.5, gt=0.0, le=20.0, description="Huber threshold in standard deviations"
    )
    landmark_min_observations: int = Field(
        3, ge=2, le=30, description="keyframes a track needs to become a landmark"
    )
    landmark_min_parallax_px: float = Field(
        15.0, gt=0.0, le=500.0, description="parallax that lets a two-view track in"
    )
    keyframe_landmark_min_parallax_deg: float = Field(
        1.0, ge=0.0, le=45.0,
        description="a published keyframe (for loop closure and maps) carries a landmark only "
        "when the cameras that see it in the window span this angle at it (its depth is fixed)",
    )  # fmt: skip
    landmark_min_depth_m: float = Field(0.1, gt=0.0, le=10.0, description="nearest landmark")
    landmark_max_depth_m: float = Field(60.0, gt=1.0, le=1e4, description="farthest landmark")
    max_reprojection_px: float = Field(
        4.0, gt=0.0, le=100.0, description="landmarks worse than this after a solve are dropped"
    )
    smoother: Literal["isam2", "batch"] = Field(
        "isam2",
        description="the window's fixed-lag smoother: isam2 (incremental) or batch "
        "(Levenberg-Marquardt over the window each keyframe; slower, the reference)",
    )
    isam2_relinearize_threshold: float = Field(
        0.01, gt=0.0, le=1.0, description="isam2: relinearise a variable that moved this much"
    )
    qr_fallback_solves: int = Field(
        10,
        ge=0,
        le=1000,
        description="a solve whose Cholesky factorisation fails (an ill-conditioned window) is "
        "redone with QR from the last good solve, and this many solves stay on QR before "
        "Cholesky again (twice as many each time Cholesky is refused again, up to 64 times); "
        "0: no fallback (the solve fails)",
    )
    restart_in_place: bool = Field(
        True,
        description="a solve that does not go through restarts the window from the last good "
        "state (no re-initialisation, the output goes on); off: a failure",
    )
    restart_inflation: float = Field(
        2.0,
        ge=1.0,
        le=1e4,
        description="restart in place: the last good state's covariances times this (on the "
        "rendered room flights, 1-16 gave a worst error after the restart of 0.06-0.13 m)",
    )
    optimizer_iterations: int = Field(
        4, ge=1, le=100, description="batch: Levenberg-Marquardt steps per keyframe"
    )
    static_window_s: float = Field(
        1.0, gt=0.1, le=30.0, description="IMU at rest this long for a static start"
    )
    static_lowpass_s: float = Field(
        0.1, gt=0.0, le=1.0, description="IMU averaged over bins this long (motor vibration)"
    )
    static_gyro_std_rad_s: float = Field(
        0.03, gt=0.0, le=1.0, description="most spread of the binned gyro at rest"
    )
    static_accel_std_m_s2: float = Field(
        0.3, gt=0.0, le=5.0, description="most spread of the binned accelerometer at rest"
    )
    static_image_motion_px: float = Field(
        1.5, gt=0.0, le=20.0, description="most median feature motion at rest"
    )
    static_velocity_sigma_m_s: float = Field(
        0.005, gt=0.0, le=1.0, description="zero-velocity constraint at rest"
    )
    static_pose_sigma_m: float = Field(
        0.002, gt=0.0, le=1.0, description="no-motion constraint at rest (and rad)"
    )
    init_attitude_sigma_rad: float = Field(
        0.01,
        gt=0.0,
        le=1.0,
        description="how well a static start's mean accelerometer gives gravity's direction "
        "(rad; times g, the sigma of the factor that ties the first roll and pitch to the "
        "accelerometer bias)",
    )
    init_accel_bias_sigma_m_s2: float = Field(
        0.2, gt=0.0, le=10.0, description="prior on the accelerometer bias at the start"
    )
    init_gyro_bias_sigma_rad_s: float = Field(
        0.005, gt=0.0, le=1.0, description="prior on the gyro bias of a static start"
    )
    fail_min_tracked: int = Field(8, ge=0, le=1000, description="fewer tracked features: failure")
    fail_max_speed_m_s: float = Field(20.0, gt=0.0, le=1e3, description="implausible speed")
    fail_max_velocity_jump_m_s: float = Field(
        3.0, gt=0.0, le=1e3, description="velocity change at a solve against the prediction"
    )
    fail_max_position_jump_m: float = Field(
        1.0, gt=0.0, le=1e3, description="position change at a solve against the prediction"
    )
    fail_max_accel_bias_m_s2: float = Field(
        2.5, gt=0.0, le=100.0, description="implausible accelerometer bias (VINS: 2.5)"
    )
    fail_max_gyro_bias_rad_s: float = Field(
        1.0, gt=0.0, le=100.0, description="implausible gyro bias (VINS: 1.0)"
    )
    fail_max_accel_bias_jump_m_s2: float = Field(
        0.5, gt=0.0, le=100.0, description="accelerometer bias change in one keyframe"
    )
    fail_max_gyro_bias_jump_rad_s: float = Field(
        0.1, gt=0.0, le=100.0, description="gyro bias change in one keyframe"
    )
    estimate_td: bool = Field(
        True,
        description="estimate the camera-IMU time offset online (VINS' estimate_td): a few "
        "milliseconds unstated cost a hand-held corridor decimetres",
    )
    td_prior_sigma_s: float = Field(
        0.003,
        gt=0.0,
        le=0.1,
        description="how far the stated camera-IMU offset may be off (s): the online estimate "
        "is weighed against it by their variances, and not used while its sigma is larger",
    )
    td_window_s: float = Field(
        30.0,
        ge=6.0,
        le=300.0,
        description="seconds of gyro and vision rotations the online time offset compares",
    )
    td_min_rate_change_rad_s2: float = Field(
        0.6,
        ge=0.0,
        le=100.0,
        description="the online time offset is used only while the gyro's rate changes by at "
        "least this much over the window (RMS, rad/s^2): on steady laps (0.1-0.4) vision's "
        "errors that follow the motion pass for an offset 10-20 ms off; MH_01 flies 1.3-1.7",
    )
    td_s: float | None = Field(
        None,
        ge=-0.1,
        le=0.1,
        description="camera-IMU offset: image taken at stamp + td_s (None: the camera's "
        "calibration, its sensor.yaml's time_offset_ns or Kalibr's timeshift_cam_imu)",
    )
    g_norm: float = Field(GRAVITY_M_S2, ge=9.0, le=10.5, description="gravity (m/s^2)")
    imu_noise_scale: float = Field(
        1.0,
        ge=0.1,
        le=100.0,
        description="multiplies the rig's stated IMU white-noise densities (a datasheet's leave out vibration)",
    )
    imu_noise_online: bool = Field(
        True,
        description="measure the IMU's white noise in flight from its readings (second "
        "differences over imu_noise_window_s) and use it on each axis where it exceeds the "
        "stated one times imu_noise_scale",
    )
    imu_noise_window_s: float = Field(
        2.0, ge=0.2, le=60.0, description="the readings the in-flight noise is measured over (s)"
    )
    accel_noise_inflation: float = Field(
        1.0,
        ge=0.1,
        le=100.0,
        description="multiplies the accelerometer's white-noise density the preintegration "
        "uses (after the in-flight measurement)",
    )
    imu_walk_scale: float = Field(
        1.0, ge=0.01, le=100.0, description="multiplies the rig's stated IMU bias random walks"
    )
    estimate_extrinsic: bool = Field(
        True,
        description="refine the camera-IMU extrinsic online around the stated one (VINS' "
        "estimate_extrinsic 1): a calibration a few tenths of a degree off costs decimetres",
    )
    extrinsic_sigma_deg: float = Field(
        1.0, gt=0.0, le=30.0, description="how far the stated extrinsic's rotation may be off"
    )
    extrinsic_sigma_m: float = Field(
        0.02, gt=0.0, le=1.0, description="how far the stated extrinsic's translation may be off"
    )
    estimate_intrinsics: bool | None = Field(
        True,
        description="refine each camera's focal lengths and principal point online, on the raw "
        "pixels through the lens model (a focal length 1 % off bends every bearing); None: with "
        "a stereo pair only (alone, the focal "
        "length trades against the scale; with the IMU's noise understated it diverged once on "
        "realistic MH_01, with it measured it helped on 6 of 7 realistic mono runs)",
    )
    intrinsics_focal_sigma: float = Field(
        0.02, gt=0.0, le=0.5, description="how far a stated focal length may be off, relative"
    )
    intrinsics_principal_sigma_px: float = Field(
        3.0, gt=0.0, le=100.0, description="how far a stated principal point may be off (px)"
    )
    stereo_extrinsic_sigma_deg: float = Field(
        0.1,
        gt=0.0,
        le=10.0,
        description="stereo: how far the stated camera-to-camera rotation "
        "may be off (the pair moves with the estimated extrinsic)",
    )
    stereo_extrinsic_sigma_m: float = Field(
        0.0003,
        gt=0.0,
        le=0.1,
        description="stereo: the same for the baseline vector (it sets the stereo scale: at "
        "1 mm, 0.9 % of EuRoC's baseline, the IMU's noise pulled realistic V1_02's scale off)",
    )
    stereo_tie_intrinsics: bool = Field(
        True,
        description="stereo, refining the intrinsics: hold the second camera's focal lengths "
        "and principal point to the first's by their stated difference (the disparity, hence "
        "the stereo scale, rests on it; each camera's own prior leaves the pair free together)",
    )
    stereo_intrinsics_focal_sigma: float = Field(
        0.002,
        gt=0.0,
        le=0.5,
        description="stereo: how far the pair's focal-length ratio may be off",
    )
    stereo_intrinsics_principal_sigma_px: float = Field(
        0.5,
        gt=0.0,
        le=100.0,
        description="stereo: how far the pair's principal-point difference may be off (px)",
    )
    stereo: bool = Field(
        False, description="use the rig's second camera: depth at once and stereo factors"
    )
    stereo_max_depth_baselines: float = Field(
        40.0,
        gt=1.0,
        le=1000.0,
        description="a track enters from one stereo pair within this depth (ORB-SLAM's ThDepth)",
    )
    stereo_init_keyframes: int = Field(
        4, ge=2, le=30, description="keyframes a stereo start in motion waits for"
    )
    stereo_pair_tolerance_s: float = Field(
        0.002, gt=0.0, le=0.05, description="largest stamp difference of a stereo pair"
    )
    stereo_max_epipolar_px: float = Field(
        2.0,
        gt=0.0,
        le=20.0,
        description="a left-right match this far off its epipolar line is dropped",
    )
    final_smoothing: bool = Field(
        False,
        description="keep the whole run's graph and, at the end, optimise all of it at once "
        "(every keyframe's IMU, observations and calibration): the final trajectory "
        "(estimate_final.tum), not causal; memory grows with the run (about 1 kB an observation)",
    )
    final_smoothing_accel_inflation: float = Field(
        1.0,
        ge=1.0,
        le=100.0,
        description="the final smoothing preintegrates the IMU again with the accelerometer's "
        "noise density times this (1: as the window had it). On realistic V1_02 motion 2 "
        "took the scale error (about 1 %) out and the error down 12-17 %, but cost 4-22 % on "
        "MH_01 and corridor1",
    )
    final_smoothing_iterations: int = Field(
        30, ge=1, le=1000, description="Levenberg-Marquardt steps of the final smoothing"
    )
    loops_as_observations: bool = Field(
        True,
        description="with loop closure, the final smoothing takes each loop as the new "
        "keyframe's observations of the old side's landmarks where it holds them (false: as "
        "the relative pose the loop measured, at its covariance). On the whole realistic "
        "MH_01 and V1_02, mono and stereo, 0.38-0.62x of no loops against 0.53-0.71x",
    )
    describe_keyframes: bool = Field(
        True, description="ORB descriptors at each keyframe's corners, for place recognition"
    )
    max_unread_keyframes: int = Field(
        200,
        ge=1,
        le=100_000,
        description="keyframe records kept until keyframes() is called; older ones are dropped",
    )
