"""Visual-inertial initialisation for a start in motion (thesis 003 §3.2, VINS-Mono's
``initialStructure`` and ``visualInitialAlign``).

Vision-only structure from motion over the window (:mod:`quadnav.vio.sfm`), the gyro bias from
its rotations, the deltas re-read under that bias, the linear alignment with gravity
refinement (:mod:`quadnav.vio.alignment`), and finally everything rotated so that gravity is
``-z`` of ``W`` and the first body has zero yaw, its position the origin.

:func:`visual_inertial_init` answers an :class:`~quadnav.vio.types.InitResult` or None;
:func:`try_visual_inertial_init` answers the result or an :class:`InitFailure` saying which
step refused and why (for the run's events). A malformed window (frame and preintegration
counts that do not match, stamps out of order, a non-finite coordinate) is a
:class:`~quadnav.errors.VioError`.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import VioError
from quadnav.geometry import Pose
from quadnav.vio.alignment import (
    AlignmentResult,
    corrected_deltas,
    gyro_bias_from_rotations,
    linear_alignment,
    rotation_residual_deg,
)
from quadnav.vio.sfm import SfmResult, refine_with_rotations, vision_sfm
from quadnav.vio.stereo_sfm import stereo_structure
from quadnav.vio.types import InitResult, InitWindow

__all__ = ["InitFailure", "InitSettings", "try_visual_inertial_init", "visual_inertial_init"]

FloatArray = NDArray[np.float64]
Stage = Literal["sfm", "gyro_bias", "alignment"]


@dataclass(frozen=True, slots=True, kw_only=True)
class InitFailure:
    """Why a window did not initialise: the step (``sfm``: too little parallax or too few
    features, a failed PnP; ``gyro_bias``: vision and gyro rotations disagree; ``alignment``:
    gravity's magnitude or the scale implausible) and a sentence for the log."""

    stage: Stage
    reason: str


def _check_window(window: InitWindow) -> None:
    n = len(window.frames)
    if len(window.preintegrations) != n - 1:
        raise VioError(
            f"an initialisation window of {n} frames needs {n - 1} preintegrations, "
            f"got {len(window.preintegrations)}"
        )
    stamps = [f.t_ns for f in window.frames]
    if any(b <= a for a, b in itertools.pairwise(stamps)):
        raise VioError(f"the initialisation window's frame stamps are not increasing: {stamps}")
    for f in window.frames:
        xy = np.asarray(f.xy)
        if xy.ndim != 2 or xy.shape[0] != len(f.ids) or xy.shape[1] not in (2, 3):
            raise VioError(f"frame {f.t_ns} ns: xy must be (N, 2) for its {len(f.ids)} ids")
        if not np.isfinite(xy).all():
            raise VioError(f"frame {f.t_ns} ns: non-finite normalised coordinates (xy)")
        if len(np.unique(f.ids)) != len(f.ids):
            raise VioError(f"frame {f.t_ns} ns: a feature id appears twice")


def _gravity_frame(g_C0: FloatArray, R_C0_B0: Rotation) -> Rotation:
    """``R_W_C0``: gravity onto ``-z``, then the yaw that leaves the first body's heading zero."""
    R_W_C0, _ = Rotation.align_vectors([[0.0, 0.0, -1.0]], [g_C0 / np.linalg.norm(g_C0)])
    yaw = (R_W_C0 * R_C0_B0).as_euler("ZYX")[0]
    return Rotation.from_euler("z", -yaw) * R_W_C0


def _to_world(
    window: InitWindow, sfm: SfmResult, al: AlignmentResult, bias: FloatArray, detail: str
) -> InitResult:
    T_B_C = window.T_B_C
    R_C_B = T_B_C.R_A_B.inv()
    R_C0_B = [T.R_A_B * R_C_B for T in sfm.T_C0_C]
    R_W_C0 = _gravity_frame(al.gravity_C0, R_C0_B[0])
    p_C0_B = np.array(
        [al.scale * T.p_A_B - R.apply(T_B_C.p_A_B) for T, R in zip(sfm.T_C0_C, R_C0_B, strict=True)]
    )
    origin = R_W_C0.apply(p_C0_B[0])
    poses = tuple(
        Pose(R_W_C0 * R, R_W_C0.apply(p) - origin) for R, p in zip(R_C0_B, p_C0_B, strict=True)
    )
    v_W = np.array([T.R_A_B.apply(v) for T, v in zip(poses, al.v_B, strict=True)])
    landmarks = {i: R_W_C0.apply(al.scale * P) - origin for i, P in sfm.points_C0.items()}
    return InitResult(
        T_W_B=poses,
        v_W_B=v_W,
        gyro_bias=bias,
        scale=al.scale,
        gravity_C0=al.gravity_C0,
        landmarks_W=landmarks,
        detail=detail,
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class InitSettings:
    """The initialisation's thresholds. ``min_parallax_px`` and ``min_features`` are VINS' (30 px
    at ``focal_px`` 460, 20 common features); ``min_translation_px`` the parallax a pure
    rotation cannot make; ``max_rotation_residual_deg`` the largest RMS disagreement of
    vision's and the gyro's relative rotations after the bias; ``max_g_norm_error_m_s2`` how
    far the unconstrained gravity may miss ``g_norm``; ``max_scale_sigma`` the largest standard
    deviation of the scale, relative to it, the alignment may leave; ``gyro_rotation_sigma_deg``
    how firmly the gyro's rotations (after the bias) hold a second bundle adjustment (0: no
    second adjustment, VINS' vision-only structure); ``estimate_gyro_bias=False`` keeps the
    bias at zero (to measure what the step is worth)."""

    min_parallax_px: float = 30.0
    focal_px: float = 460.0
    min_features: int = 20
    min_translation_px: float = 5.0
    max_rotation_residual_deg: float = 3.0
    max_g_norm_error_m_s2: float = 1.0
    #: 3 %: at 5 %, starts made a frame or two earlier on realistic V1_02 and corridor1 were
    #: worse (V1_02 seed 4 mono: 0.109 m against 0.070 m; the results of 2026-12-02, part 5)
    max_scale_sigma: float = 0.03
    gyro_rotation_sigma_deg: float = 0.05
    estimate_gyro_bias: bool = True


def try_visual_inertial_init(
    window: InitWindow, *, settings: InitSettings | None = None
) -> InitResult | InitFailure:
    """The window's metric, gravity-aligned start, or the step that refused and why."""
    _check_window(window)
    cfg = settings or InitSettings()
    stereo = window.T_L_R is not None and len(window.frames[0].stereo_ids) > 0
    sfm: SfmResult | str = "no stereo pair"
    why_not_stereo = ""
    if window.T_L_R is not None and stereo:
        sfm = stereo_structure(
            window.frames, window.T_L_R, focal_px=cfg.focal_px, min_points=cfg.min_features
        )
    if isinstance(sfm, str):  # one camera, or too few stereo points: the structure from motion
        if stereo:
            why_not_stereo = f" (stereo: {sfm})"
        stereo = False
        sfm = vision_sfm(
            window.frames,
            focal_px=cfg.focal_px,
            min_parallax_px=cfg.min_parallax_px,
            min_common=cfg.min_features,
            min_translation_px=cfg.min_translation_px,
        )
    if isinstance(sfm, str):
        return InitFailure(stage="sfm", reason=sfm + why_not_stereo)
    R_C_B = window.T_B_C.R_A_B.inv()
    R_C0_B = [T.R_A_B * R_C_B for T in sfm.T_C0_C]
    pims = window.preintegrations
    bias = gyro_bias_from_rotations(R_C0_B, pims) if cfg.estimate_gyro_bias else np.zeros(3)
    rot_err = rotation_residual_deg(R_C0_B, pims, bias)
    if not np.isfinite(rot_err) or rot_err > cfg.max_rotation_residual_deg:
        return InitFailure(
            stage="gyro_bias",
            reason=f"vision and gyro rotations disagree by {rot_err:.2f} deg RMS after the bias",
        )
    deltas = [corrected_deltas(p, bias) for p in pims]
    if cfg.gyro_rotation_sigma_deg > 0.0:
        R_B_C = window.T_B_C.R_A_B
        gyro = [R_C_B * d.dR * R_B_C for d in deltas]
        sigma = float(np.radians(cfg.gyro_rotation_sigma_deg))
        refined = refine_with_rotations(
            window.frames, sfm, gyro, sigma_rad=sigma, focal_px=cfg.focal_px
        )
        if isinstance(refined, str):
            return InitFailure(stage="sfm", reason=refined)
        sfm = refined
        R_C0_B = [T.R_A_B * R_C_B for T in sfm.T_C0_C]
    al = linear_alignment(
        np.array([T.p_A_B for T in sfm.T_C0_C]),
        R_C0_B,
        deltas,
        window.T_B_C.p_A_B,
        g_norm=window.g_norm,
        max_g_norm_error_m_s2=cfg.max_g_norm_error_m_s2,
        max_scale_sigma=cfg.max_scale_sigma,
        scale=1.0 if stereo else None,
    )
    if isinstance(al, str):
        return InitFailure(stage="alignment", reason=al + why_not_stereo)
    if stereo:
        detail = (
            f"stereo: {len(window.frames)} keyframes, {len(sfm.points_C0)} landmarks, "
            f"reprojection {sfm.reprojection_px:.2f} px, gyro bias {np.round(bias, 4).tolist()} rad/s"
        )
        return _to_world(window, sfm, al, bias, detail)
    detail = (
        f"visual: reference frame {sfm.reference} ({sfm.parallax_px:.0f} px parallax), "
        f"{len(sfm.points_C0)} landmarks, reprojection {sfm.reprojection_px:.2f} px, "
        f"scale {al.scale:.3f} (sigma {al.scale_sigma / al.scale:.1%}), gyro bias {np.round(bias, 4).tolist()} rad/s"
        f"{why_not_stereo}"
    )
    return _to_world(window, sfm, al, bias, detail)


def visual_inertial_init(
    window: InitWindow, *, settings: InitSettings | None = None
) -> InitResult | None:
    """:func:`try_visual_inertial_init`, None when the window cannot initialise (call that
    function for the reason)."""
    out = try_visual_inertial_init(window, settings=settings)
    return out if isinstance(out, InitResult) else None
