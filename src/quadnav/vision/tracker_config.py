"""The KLT front end's settings (:class:`TrackerConfig`), apart from the tracker itself so that
a configuration holding them (a VIO's, a scenario's) validates without importing OpenCV."""

from __future__ import annotations

from pydantic import Field, field_validator

from quadnav.config_model import ConfigModel

__all__ = ["TrackerConfig"]


class TrackerConfig(ConfigModel):
    """The front end's settings, named after VINS-Mono's config where it has them."""

    max_features: int = Field(
        150, ge=10, le=1000, description="features per frame (VINS' max_cnt; 150-300 usual)"
    )
    min_distance_px: float = Field(
        30.0, ge=1.0, le=200.0, description="least distance between two features (VINS' min_dist)"
    )
    fb_threshold_px: float = Field(
        0.5, gt=0.0, le=5.0, description="forward-backward check: most a feature may miss its start"
    )
    forward_backward: bool = Field(True, description="track back and drop the inconsistent")
    fb_pyramid_levels: int | None = Field(
        None,
        ge=0,
        le=6,
        description="pyramid levels of the backward pass, which starts at the feature's known "
        "start (None: pyramid_levels; VINS-Fusion: 1, faster, but on realistic MH_01 seed 0 the "
        "mono ATE went from 0.022 to 0.027 m)",
    )
    ransac_threshold_px: float = Field(
        1.0, gt=0.0, le=10.0, description="fundamental-matrix RANSAC (VINS' F_threshold)"
    )
    ransac: bool = Field(True, description="drop outliers of a fundamental matrix")
    pyramid_levels: int = Field(3, ge=0, le=6, description="KLT pyramid levels above the image")
    predicted_pyramid_levels: int | None = Field(
        None,
        ge=0,
        le=6,
        description="pyramid levels of the forward pass when it starts from the gyro's "
        "prediction (None: pyramid_levels)",
    )
    window_px: int = Field(21, ge=3, le=61, description="KLT window side, odd")
    klt_iterations: int = Field(30, ge=1, le=100, description="KLT iterations per level")
    quality_level: float = Field(
        0.01, gt=0.0, lt=1.0, description="Shi-Tomasi: weakest corner / strongest corner"
    )
    equalize: bool = Field(False, description="CLAHE before tracking (VINS' equalize, dark images)")
    detect_min_new: int = Field(
        1,
        ge=1,
        le=1000,
        description="detect corners only when this many are missing (VINS: 1, every frame)",
    )

    @field_validator("window_px")
    @classmethod
    def _odd(cls, v: int) -> int:
        if v % 2 == 0:
            raise ValueError(f"window_px must be odd, got {v}")
        return v
