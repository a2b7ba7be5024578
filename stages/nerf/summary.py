"""The nerf stage's summary, one model on both sides: the stage writes it into its manifest,
`NerfView.summary` reads it back, and report, bench and batch read its fields by name."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict

from endopipe.pipeline.stage import Summary
from endopipe.stages.metrics.scores import DepthScores


class Movement(BaseModel):
    """How far refinement moved the cameras: median and max over the frames (world units, % of
    the camera path's length, degrees)."""

    model_config = ConfigDict(extra="forbid")

    median_translation: float | None = None
    max_translation: float | None = None
    median_translation_pct: float | None = None
    max_translation_pct: float | None = None
    median_rotation_deg: float | None = None
    max_rotation_deg: float | None = None


class PoseRefineRecord(Movement):
    """Whether pose refinement ran and how far the training frames' cameras moved (and, when
    they were fitted too, the held-out ones')."""

    ran: bool
    heldout_refined: bool | None = None
    heldout: Movement | None = None


#: The colour channels in the order the albedo's lists give them.
CHANNELS = ("red", "green", "blue")


class ColourRefit(BaseModel):
    """Whether a colour channel's albedo sat at its ceiling after training, and the steps that
    then fitted the albedo again with the geometry fixed (colour_phase.py)."""

    model_config = ConfigDict(extra="forbid")

    ceiling: list[float]  # R, G, B: share of a draw of training rays with the albedo over 0.95
    asked: list[float] | None = None  # ... the median albedo its pixels ask, in ceilings
    light_factor: float | None = None  # the light's gain multiplied by this for the refit
    steps: int = 0  # the albedo's steps (0: no channel was pinned)
    seconds: float = 0.0
    ceiling_after: list[float] | None = None  # ... the same draw after them


class NerfDepthScores(BaseModel):
    """The held-out frames' depth against the ground truth, by the protocols the truth supports
    (stages/metrics/depth.py `sequence_protocol`): the metric ones, `unscaled` only with metric
    poses; an affine proxy of depth (C3VD's panel) the affine-invariant one alone."""

    model_config = ConfigDict(extra="forbid")

    median_scaled: DepthScores | None = None
    sequence_scaled: DepthScores | None = None
    unscaled: DepthScores | None = None
    affine_invariant: DepthScores | None = None


class NerfSummary(Summary):
    steps: int  # steps trained
    planned_steps: int | None = None  # train.steps
    budget_stopped: bool = False  # the time budget ended training before planned_steps
    train_frames: int
    heldout_frames: int
    train_s: float
    rays_per_s: float
    render_ms: float | None = None  # one held-out frame through the field, colour and depth
    heldout_psnr: float | None = None
    train_psnr: float | None = None  # the fit: training frames rendered after training
    neighbour_psnr: float | None = None  # the held-out frames guessed from their neighbours
    fit: str | None = None  # learned | learned, not held out | not learned (nerf/fit.py)
    depth: NerfDepthScores | None = None
    resumed_from: int = 0
    device: str = "cpu"
    threads: int = 1
    pose_refine: PoseRefineRecord | None = None
    grid_warp: bool | None = None  # the grid warped beyond the camera path (field.warp)
    core_fraction: float | None = None  # L_prior's empty core used (fraction of the wall)
    geometry: str | None = None  # density or sdf, as field.geometry resolved for this case
    #: a dynamic field (field.dynamic resolved on): its nodes along time; None: static
    time_nodes: int | None = None
    #: whether measured depth trained the field (SfM points, stereo, given depth, a depth prior):
    #: its expected depth is then what those rays fit (depth.field_depth auto); None: not recorded
    depth_supervised: bool | None = None
    #: the albedo's ceiling measured after training, and its refit (None: not measured)
    colour_refit: ColourRefit | None = None
    #: why no field was trained (a stereo pair alone); None: trained
    skipped: str | None = None
