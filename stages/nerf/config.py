"""The nerf stage's config tree: field, sampling, losses, training (a run is a filled-in config).

Defaults are the fast CPU setting (TensoRF VM grid, two-pass sampling). The paper's exact setting
(seed §4.3) is the `paper` preset, endopipe/configs/paper.yaml (docs/method.md). The field's
section is field_config.py, the losses' loss_config.py; the others and the tree are here.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from endopipe.pipeline.stage import StageConfig
from endopipe.stages.nerf.config_section import ConfigSection
from endopipe.stages.nerf.field_config import FieldConfig
from endopipe.stages.nerf.loss_config import LossConfig


class ShadingConfig(ConfigSection):
    """Near-light model (seed §3.2) and the scope's photometry:
    colour = (F(theta) * albedo * (gain * max(n.l, 0) / r^2 + ambient) * exposure)^(1/gamma)."""

    enabled: bool = Field(
        True, description="Use the near-light shading; off: colour = albedo (plain NeRF)."
    )
    gamma: float = Field(
        2.2,
        gt=0,
        description="Display gamma of the frames: rendered linear colour is encoded with "
        "x^(1/gamma) before it is compared with the pixels (1: linear frames).",
    )
    ambient: float = Field(0.02, ge=0, description="Initial ambient term (learned).")
    learn_gain: bool = Field(True, description="Learn the light gain (else keep the initial one).")
    exposure: bool | Literal["auto"] = Field(
        "auto",
        description="Learn a per-frame exposure (log gains a colour channel, zero-mean over "
        "the training frames; a held-out frame takes its trained neighbours'). auto: on for a "
        "moving camera with no lumen prior (the scope's exposure follows what it looks at: "
        "the sinus recording's mean brightness moves 2x over its first window), off "
        "otherwise.",
    )
    falloff: Literal["none", "learned"] = Field(
        "none",
        description="Radial falloff F(theta) of the light and the lens (theta: a ray's angle "
        "to the optical axis): none: F = 1 (the seed); learned: F = exp(sum_k a_k "
        "(1 - cos theta)^k), k = 1..3, from a flat start. With the light at the camera the "
        "emission profile and the vignetting are both functions of theta: one F models both.",
    )
    learn_gamma: bool = Field(
        False,
        description="Learn the camera response as a gamma (starting from `gamma`); off: "
        "`gamma` is fixed.",
    )
    lr: float = Field(
        0.01,
        gt=0,
        description="Learning rate of the falloff coefficients, the learned gamma and the "
        "per-frame exposures.",
    )
    normal_term: bool = Field(
        True,
        description="Light the surface by the cosine between its normal and the light (n.l): "
        "shading as a cue to shape. Off: the light falls off with distance only.",
    )
    normal_eps: float = Field(
        1.0, gt=0, description="Finite-difference step of the density gradient, in grid cells."
    )
    normal_warmup: float = Field(
        0.1,
        ge=0,
        le=1,
        description="Fraction of training over which the n.l term fades in (starts as 1).",
    )

    @property
    def tilt(self) -> bool:
        """Whether the surface's normal lights it (n.l): the shading is on with its tilt."""
        return self.enabled and self.normal_term


class SamplingConfig(ConfigSection):
    """Samples along each ray; bounds come from the lumen prior's ray_bounds."""

    sampler: Literal["two_pass", "coarse_fine"] = Field(
        "two_pass",
        description="two_pass: density-only pass without gradients, then resampled samples "
        "with gradients (fast); coarse_fine: the paper's stratified coarse + importance fine.",
    )
    n_coarse: int = Field(48, ge=2, description="Samples of the first pass per ray.")
    n_fine: int = Field(
        16, ge=1, description="Samples of the second pass per ray (importance + uniform)."
    )
    n_uniform: int = Field(
        4, ge=0, description="two_pass: how many of n_fine are stratified, not importance-drawn."
    )
    render_coarse: int = Field(
        32, ge=2, description="two_pass, rendering (eval mode): samples of the first pass."
    )
    render_fine: int = Field(
        16, ge=1, description="two_pass, rendering (eval mode): importance samples per ray."
    )
    spacing: Literal["log", "linear"] = Field(
        "log", description="Spacing of the first pass in depth (log: denser close to the camera)."
    )
    bounds: Literal["prior", "box"] = Field(
        "prior",
        description="Ray bounds from the lumen prior's ray_bounds (default), or from the scene "
        "box (an ablation: a plain NeRF's fixed bounds).",
    )
    bounds_margin: float = Field(
        0.5, ge=0, description="The prior's wall is inflated by (1 + margin) to get the far bound."
    )
    far_radii: float = Field(
        12.0, gt=0, description="Cap of the far bound, in lumen radii (looking down the lumen)."
    )
    near_fraction: float = Field(
        0.05, gt=0, description="Near bound as a fraction of the lumen radius at the camera."
    )
    open_tube_ends: bool = Field(
        True,
        description="A ray that leaves the tube prior past either end of its centerline (where "
        "the wall is extrapolated straight, not seen) is not bounded there: far = the cap.",
    )
    chunk: int = Field(
        4096,
        ge=256,
        description="Rays per chunk when rendering whole images (the same pixels at any size; "
        "on two CPU cores a held-out frame of C3VD renders in 1.10 s at 4096 against 1.54 s at "
        "8192 and 1.36 s at 2048: scripts/bench_render_chunk.py).",
    )
    proposal: bool | Literal["auto"] = Field(
        "auto",
        description="two_pass, training: the first pass reads a coarse copy of the density on "
        "a dense grid (nerf/proposal.py), refreshed as training goes, instead of the field. "
        "auto: on where a lumen prior shapes the density, off without one (the sinus window "
        "with no prior: depth AbsRel 0.153 with it, 0.108 without).",
    )
    proposal_res: int = Field(
        128, ge=8, description="Cells of the proposal grid along the box's longest side."
    )
    proposal_every: int = Field(
        16, ge=1, description="Steps between refreshes of a share of the proposal's cells."
    )
    proposal_share: float = Field(
        0.25, gt=0, le=1, description="Share of the proposal's cells each refresh evaluates."
    )


class TrainConfig(ConfigSection):
    """Optimisation, schedule, hold-out, checkpoints."""

    steps: int = Field(1500, ge=1, description="Optimisation steps (at most).")
    time_budget_s: float | None = Field(
        600.0,
        gt=0,
        description="A last resort against a slow or loaded machine (s): past it the schedules "
        "run on max(step / steps, time / budget) and training ends when either is done, so the "
        "result then depends on the machine; the log, summary and report say at which step "
        "(null: all steps, always). It is the budget of `steps`: a still camera's multiple of "
        "the steps (`still_steps`) multiplies it too.",
    )
    still_steps: float = Field(
        4.0,
        ge=1.0,
        description="A still camera's steps, as a multiple of `steps`: its field is starved of "
        "rays, and a held-out frame is a new time from the same view, which more steps bring "
        "closer (the cutting clip's 20 held-out frames from the same poses: 33.05 dB at 2x, "
        "33.93 at 3x, 34.46 at 4x: 6000 steps, trained in 481 s at 12,800 rays a second on two "
        "cores); a moving camera's more steps fit its training frames, not "
        "its new views (the sinus window: 24.84 dB at 2250 steps against 24.89 at 1500).",
    )
    batch_rays: int = Field(1024, ge=16, description="Rays per step.")
    frames_per_step: int | Literal["auto"] = Field(
        "auto",
        description="Training frames a step's rays are drawn from (0: each ray from any). A "
        "field over time then reads its lines sliced at those few times instead of each "
        "ray's corners in (w, time). auto: 8 for a field whose geometry changes with time (a "
        "still camera's: the cutting clip at 2250 steps in 326 s against 344, held-out 30.30 "
        "dB against 30.31), 0 otherwise (a moving camera's step sees its views from every "
        "part of the path).",
    )
    lr_grid: float = Field(0.02, gt=0, description="Learning rate of grid / hash parameters.")
    lr_mlp: float = Field(1e-3, gt=0, description="Learning rate of MLP parameters.")
    lr_decay: float = Field(
        0.1, gt=0, le=1, description="Learning rates decay exponentially to this factor at the end."
    )
    holdout_every: int = Field(
        8,
        ge=0,
        description="Frames with index % holdout_every == 0 are held out (not trained on, "
        "evaluated); 0: train on all.",
    )
    seed: int = Field(0, description="Seed of initialisation and ray sampling.")
    checkpoint_every: int = Field(
        250,
        ge=1,
        description="Steps between atomic checkpoints (at 384 nodes one holds 250 MB with the "
        "optimiser's state: a quarter of a second to write).",
    )
    log_every: int = Field(10, ge=1, description="Steps between rows of train_log.csv.")
    device: Literal["auto", "cpu", "cuda"] = Field(
        "auto", description="auto: a GPU when torch sees one, else the CPU."
    )
    threads: int = Field(
        0, ge=0, description="torch CPU threads (0: the cores not busy with other processes)."
    )
    eval_frames: int = Field(
        0, ge=0, description="Evaluate at most this many held-out frames (0: all of them)."
    )
    colour_steps: int = Field(
        600,
        ge=0,
        description="After training, steps that fit the albedo again with the geometry, poses "
        "and exposures fixed and the light made brighter, when a colour channel's albedo sits "
        "at its ceiling on more than `colour_ceiling` of the training rays (that channel all "
        "shading: the field could not render what it saw; the depth stays the same to the bit). "
        "The steps read a pool of training rays rendered once through the fixed geometry, as "
        "frames are rendered. C3VD preview: held-out PSNR 31.0 dB against 24.1, the depth the "
        "same, in about 60 s more on two torch threads (not counted in time_budget_s). 0: never.",
    )
    colour_ceiling: float = Field(
        0.5,
        ge=0.0,
        le=1.0,
        description="Share of the training rays with a channel's albedo over 0.95 that starts "
        "`colour_steps` (C3VD's red: 1.0; the sinus, Hamlyn and cutting clips: 0.06-0.24).",
    )
    fit_frames: int = Field(
        3,
        ge=0,
        description="Training frames rendered after training to measure the fit (spread over "
        "the sequence; 0: none, and no word on whether the field learned its images).",
    )

    @field_validator("frames_per_step")
    @classmethod
    def _frames_not_negative(cls, v: int | str) -> int | str:
        if isinstance(v, int) and v < 0:
            raise ValueError("must be 0 or more, or auto")
        return v


class PoseRefineConfig(ConfigSection):
    """Joint refinement of the camera poses with the field: a per-frame SE(3) correction in the
    camera's own frame, c2w @ exp(delta) (see pose_refine.py)."""

    mode: Literal["auto", "on", "off"] = Field(
        "off",
        description="auto: on when the poses come from COLMAP SfM (poses.source=colmap), off "
        "for ground-truth or file poses; on / off: always / never. Off by default: on a tube "
        "with known perturbed poses it did not yet reduce the pose error.",
    )
    lr: float = Field(
        1e-3,
        ge=0,
        description="Adam learning rate of the corrections (radians and lumen radii); it "
        "decays with the others.",
    )
    start: float = Field(
        0.1,
        ge=0,
        lt=1,
        description="Fraction of training on the given poses before they move: the coarse "
        "field settles first (the grid's upsampling is the coarse to fine).",
    )
    warmup: float = Field(
        0.1,
        ge=0,
        le=1,
        description="Fraction of training over which the learning rate ramps up from start.",
    )
    l2: float = Field(
        1e-3,
        ge=0,
        description="Weight of the mean squared correction: keeps the poses near the given ones "
        "where the images say little.",
    )
    heldout_steps: int = Field(
        100,
        ge=0,
        description="After training, steps fitting only the held-out frames' corrections, the "
        "field frozen, so held-out PSNR measures the field, not the pose error (0: off).",
    )
    heldout_rays: int = Field(
        512, ge=16, description="Rays per held-out refinement step (spread over the frames)."
    )

    @field_validator("mode", mode="before")
    @classmethod
    def _yaml_on_off(cls, value: object) -> object:
        """YAML reads a bare on / off (`--set nerf.pose_refine.mode=on`) as a boolean."""
        if isinstance(value, bool):
            return "on" if value else "off"
        return value


class FarViewConfig(ConfigSection):
    """Regularisers added when `field.warp: auto` leaves the grid unwarped (a scope that looks
    far): its far cells are then as fine as the near ones and each is seen by few pixels, so
    these and a coarser grid take the place of the smoothing that growing cells gave (C3VD:
    at 384 nodes a plane of the grid showed as a crease down the near wall)."""

    tv_weight: float = Field(
        1.0, ge=0, description="Total-variation penalty on the density planes (at least this)."
    )
    distortion_weight: float = Field(
        0.01, ge=0, description="Distortion loss, one surface per ray (at least this)."
    )
    res_final: int | None = Field(
        192,
        ge=8,
        description="Grid nodes along the longest side at most (None: field.tensorf.res_final).",
    )


class NerfConfig(StageConfig):
    field: FieldConfig = Field(default_factory=FieldConfig, description="The radiance field.")
    shading: ShadingConfig = Field(default_factory=ShadingConfig, description="Near-light model.")
    sampling: SamplingConfig = Field(default_factory=SamplingConfig, description="Ray sampling.")
    loss: LossConfig = Field(default_factory=LossConfig, description="Loss terms and weights.")
    train: TrainConfig = Field(default_factory=TrainConfig, description="Training.")
    pose_refine: PoseRefineConfig = Field(
        default_factory=PoseRefineConfig, description="Joint camera pose refinement."
    )
    far_view: FarViewConfig = Field(
        default_factory=FarViewConfig,
        description="Added regularisers and a coarser grid when field.warp: auto leaves the grid "
        "unwarped.",
    )
