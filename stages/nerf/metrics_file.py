"""04_nerf/metrics.json (docs/formats.md), the held-out evaluation, as one model: the nerf stage
writes it through `NerfMetrics.write`, `NerfView.metrics` reads it back, and the report reads
its fields."""

from __future__ import annotations

from pydantic import ConfigDict

from endopipe.stages.metrics.files import MetricsFile
from endopipe.stages.nerf.summary import NerfDepthScores


class NerfMetrics(MetricsFile):
    """The frames held out of training, rendered after it: which, how fast, their PSNR and,
    with ground-truth depth, their depth scores. Keys another version wrote are kept."""

    model_config = ConfigDict(extra="allow", ser_json_inf_nan="constants")

    heldout: list[int] = []  # the frames evaluated
    render_rgb_ms: float | None = None  # median time to render one, colour and depth
    psnr: float | None = None  # mean over them, on their usable pixels
    neighbour_psnr: float | None = None  # ... each guessed as its two neighbours' average
    # A field with an exposure a frame: each held-out render's (and neighbour average's) exposure
    # fitted to the frame's left half (metrics/exposure.py); the PSNR with the exposure the
    # trained neighbours interpolate, before that fit.
    exposure_fitted: bool = False
    psnr_exposure_interpolated: float | None = None
    train_psnr: float | None = None  # a few training frames rendered (the fit), same pixels
    fit_frames: list[int] = []  # ... which
    fit: str | None = None  # fit.py's word: learned | learned, not held out | not learned
    fit_said: str | None = None  # ... and its line with the figures
    depth: NerfDepthScores | None = None  # with ground-truth depth
    depth_frames: int | None = None  # ... on this many of them
