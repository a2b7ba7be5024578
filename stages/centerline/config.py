"""The centerline stage's settings: the curve's smoothing and extension, recentring on the
points' circles, the radius profile and its fallbacks.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from endopipe.pipeline.stage import StageConfig


class CenterlineConfig(StageConfig):
    prior: Literal["auto", "tube", "cavity", "none"] = Field(
        "auto",
        description="auto: the candidate (tube or cavity) that predicts the SfM points' depths "
        "best, or none when neither predicts min_fit of them; tube: a curve with a radius "
        "(colon); cavity: an ellipsoid (stomach); none: no anatomical prior.",
    )
    given_prior: str | None = Field(
        None,
        description="A folder holding a prior fitted over a longer stretch of the same frames "
        "(prior.npz, and cameras.json: that reconstruction's camera centres by input frame), "
        "used instead of this case's own, placed by the cameras both registered. A short "
        "recording gives its windows the lumen of its one SfM this way.",
    )
    insist: bool = Field(
        False,
        description="Keep a prior set by the config (tube / cavity) even when the SfM points "
        "contradict it (it predicts under min_fit of their depths while the other shape "
        "predicts more); off: such a prior yields to the shape that fits, and says so.",
    )
    fit_tolerance: float = Field(
        0.25,
        gt=0,
        description="A camera-to-point ray agrees with a prior when the prior's wall is met "
        "within this relative distance of the point.",
    )
    min_fit: float = Field(
        0.5,
        ge=0,
        le=1,
        description="auto: the share of agreeing rays a prior needs to be used. A chosen "
        "prior's share also scales L_prior's weight (a prior set by the config has its full "
        "weight).",
    )
    reach_margin: float = Field(
        1.25,
        ge=1,
        description="Rays reach this multiple of the farthest SfM points the cameras saw "
        "(98th percentile per frame).",
    )
    reach_share: float = Field(
        0.9,
        gt=0,
        lt=1,
        description="A chosen prior's rays are sampled past its wall until they reach this "
        "share of the SfM points the cameras saw (the wall inflated by the least margin that "
        "holds them, never less than nerf.sampling.bounds_margin).",
    )
    core_share: float = Field(
        0.02,
        ge=0,
        lt=1,
        description="A chosen prior's empty core (where L_prior penalises density) is shrunk "
        "until at most this share of the SfM observations lie inside it (never wider than "
        "nerf.loss.core_fraction).",
    )
    free_scale: float = Field(
        0.3,
        gt=0,
        description="prior none: the scene's length unit (the NeRF's grid and steps are sized in "
        "it) as a fraction of the median camera-to-point distance.",
    )
    n_samples: int = Field(256, ge=16, le=4096, description="Samples of the output curve.")
    smoothing: float = Field(
        1.0,
        ge=0,
        description="Spline smoothing s = smoothing x n x wobble^2 (wobble: the path's scatter "
        "about a local-linear fit one radius wide). 0 interpolates the cameras.",
    )
    smooth_radii: float = Field(
        1.0, gt=0, description="Width of the local-linear fit that measures the wobble, in radii."
    )
    extend_ahead: float = Field(
        1.0, ge=0, description="Extend the curve past the cameras it looks towards, in radii."
    )
    extend_behind: float = Field(
        0.5, ge=0, description="Extend the curve past the cameras it looks away from, in radii."
    )
    min_cameras: int = Field(
        5, ge=2, description="Fewer registered cameras than this: a line (PCA axis), no spline."
    )
    recentre: bool = Field(
        True, description="Move the curve onto the axis of circles fitted to the points."
    )
    recentre_iters: int = Field(2, ge=0, le=10, description="Rounds of recentring.")
    max_shift: float = Field(
        0.5, ge=0, description="Largest recentring offset accepted for a slice, in radii."
    )
    min_sectors: int = Field(
        6,
        ge=3,
        le=8,
        description="A slice's circle counts when its points fill this many of "
        "8 angular sectors around the curve.",
    )
    recentre_bin_width: float = Field(
        0.5, gt=0, description="Slice width of the circle fits, along the curve, in radii."
    )
    recentre_smoothing: float = Field(
        1.0, gt=0, description="Gaussian smoothing of the recentring offsets, in radii."
    )
    bin_width: float = Field(
        0.2, gt=0, description="Slice width of the radius estimate, along the curve, in radii."
    )
    radius_smoothing: float = Field(
        0.25, gt=0, description="Gaussian smoothing of the radius along the curve, in radii."
    )
    min_points_per_bin: int = Field(12, ge=3, description="Points a slice needs to count.")
    min_points: int = Field(
        30, ge=3, description="Fewer usable points: no radius profile (global median fallback)."
    )
    outlier_mad: float = Field(3.0, gt=0, description="Outlier rejection at this many MADs.")
    max_points: int = Field(
        200_000, ge=1000, description="Subsample the sparse points to at most this many."
    )
    default_radius_mm: float = Field(
        15.0, gt=0, description="Radius when no points are usable and cameras are metric (mm)."
    )
    default_radius_fraction: float = Field(
        0.1,
        gt=0,
        description="Radius when no points are usable and cameras are not metric, as a fraction "
        "of the camera path length.",
    )
    far_radii: float = Field(
        6.0, gt=0, description="The prior's default cap for ray far bounds, in radii."
    )
