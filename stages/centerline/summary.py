"""The centerline stage's summary, one model on both sides: the stage writes it into its manifest,
`CenterlineView.summary` reads it back, and report, bench and batch read its fields by name."""

from __future__ import annotations

from endopipe.pipeline.stage import Summary
from endopipe.stages.centerline.choose import PriorScore


class CenterlineSummary(Summary):
    kind: str  # the prior the NeRF uses: tube | cavity | none
    prior_reason: str = ""
    prior_weight: float = 1.0
    prior_scores: list[PriorScore] = []
    reach: float | None = None
    wall_margin: float = 0.0  # reach_share of the SfM points lie within (1 + it) x the wall
    core_limit: float = 1.0  # the widest empty core the SfM points allow (fraction of the wall)
    length: float
    mean_radius: float
    radius_source: str
    radius_note: str
    n_points_used: int
    n_cameras: int
    units: str
    recentred_slices: int = 0
    #: against a ground-truth centerline (synthetic cases): mean distance, and radius error
    centerline_mean_dist: float | None = None
    centerline_mean_dist_pct_of_radius: float | None = None
    radius_error_pct: float | None = None
