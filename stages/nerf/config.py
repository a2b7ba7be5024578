"""The nerf stage's config tree: field, sampling, losses, training (a run is a filled-in config).

Defaults are the fast CPU setting (TensoRF VM grid, two-pass sampling). The paper's exact setting
(seed §4.3) is the `paper` preset, endopipe/configs/paper.yaml (docs/method.md).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from endopipe.pipeline.stage import StageConfig


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class TensorfConfig(_Section):
    """TensoRF vector-matrix grid (the CPU default)."""

    density_components: int = Field(
        16,
        ge=1,
        description="VM components per plane for density (8 underfits the colon's folds: mesh "
        "7.2% of the radius off vs 6.8% at 16, two seeds; 32: no better, slower).",
    )
    appearance_components: int = Field(
        32, ge=1, description="VM components per plane for the albedo features."
    )
    appearance_dim: int = Field(27, ge=1, description="Albedo feature size fed to the colour MLP.")
    res_init: int = Field(
        96, ge=8, description="Grid nodes along the scene box's longest side at the start."
    )
    res_final: int = Field(
        384, ge=8, description="Grid nodes along the longest side after the last upsampling."
    )
    upsample_at: list[float] = Field(
        default_factory=lambda: [0.15, 0.3, 0.45],
        description="When to upsample the grid, as fractions of train.steps (log-spaced "
        "resolutions from res_init to res_final).",
    )
    composite_features: bool = Field(
        True,
        description="Composite the albedo features along the ray and run the colour MLP once "
        "per ray (fast); off: the MLP runs on every sample.",
    )
    tv_weight: float = Field(
        0.0, ge=0.0, description="Total-variation penalty on the density planes (0: off)."
    )


class HashgridConfig(_Section):
    """Instant-NGP hash grid in pure PyTorch (for GPU users; slow on a CPU)."""

    levels: int = Field(16, ge=1, description="Resolution levels.")
    features: int = Field(2, ge=1, description="Features per level.")
    log2_size: int = Field(19, ge=8, le=24, description="log2 of the hash table rows per level.")
    base_res: int = Field(16, ge=2, description="Coarsest level's resolution.")
    max_res: int = Field(1024, ge=4, description="Finest level's resolution.")
    hidden: int = Field(64, ge=8, description="Width of the density MLP.")
    geo_features: int = Field(15, ge=1, description="Features passed from density to colour MLP.")


class PositionalConfig(_Section):
    """The paper's coordinate MLP (seed §3.1, §4.3): ReLU MLP over sinusoidal encodings."""

    depth: int = Field(8, ge=2, description="Fully connected layers.")
    width: int = Field(256, ge=8, description="Hidden units per layer.")
    skip: int = Field(4, ge=0, description="Layer that gets the encoded input again (0: none).")
    pos_bands: int = Field(10, ge=0, description="Frequency bands for positions.")


class SdfConfig(_Section):
    """A signed distance d(x) (scene units, positive in the free lumen) as the field's geometry:
    one surface per ray by construction, sigma = Psi_beta(-d) / beta (VolSDF's Laplace CDF)."""

    beta_init: float = Field(
        0.1, gt=0, description="Width of the surface's density ramp at the start (scene units)."
    )
    beta_final: float = Field(
        0.01, gt=0, description="... at the end (geometric schedule over training)."
    )
    start_nodes: int = Field(
        96,
        ge=8,
        description="Nodes along the box's longest side of the fixed grid that holds the "
        "starting distance (the prior's wall, or spheres about the cameras).",
    )
    residual_scale: float = Field(
        0.3, gt=0, description="The learned residual's scale over the starting distance."
    )
    eikonal_weight: float = Field(
        0.005,
        ge=0,
        description="Weight of (|grad d| - 1)^2 (bench colon: 0.1 smooths the folds away, "
        "Chamfer 5.5% of the radius against 4.2% at 0.005).",
    )
    eikonal_points: int = Field(
        2048,
        ge=16,
        description="Points per step for the eikonal term, drawn between the batch's rays' "
        "near and far bounds.",
    )


class FieldConfig(_Section):
    """Density sigma(x) and a view-independent albedo a(x)."""

    geometry: Literal["auto", "density", "sdf"] = Field(
        "auto",
        description="density: a free density (haze allowed); sdf: a signed distance whose "
        "zero level is the surface, learned as a residual over the prior's wall; auto: sdf "
        "with the cavity prior (two synthetic cavities: depth AbsRel 0.014 / 0.011 against "
        "0.032 / 0.015), density otherwise (worse with sdf: the bench colon, C3VD).",
    )
    sdf: SdfConfig = Field(default_factory=SdfConfig, description="Signed-distance settings.")

    encoding: Literal["tensorf", "hashgrid", "positional"] = Field(
        "tensorf",
        description="tensorf: fastest on a CPU (default); hashgrid: for GPUs; positional: the "
        "paper's 8x256 MLP.",
    )
    tensorf: TensorfConfig = Field(default_factory=TensorfConfig, description="TensoRF settings.")
    hashgrid: HashgridConfig = Field(default_factory=HashgridConfig, description="Hash grid.")
    positional: PositionalConfig = Field(
        default_factory=PositionalConfig, description="Positional-encoding MLP."
    )
    dynamic: bool | Literal["auto"] = Field(
        "auto",
        description="A field that changes with time (HexPlane's space-time planes on the "
        "TensoRF grid): every frame is fitted and rendered at its own time. auto: on when the "
        "poses stage found the scene moving under a still camera (tissue pulled, cut or "
        "breathing; instruments), false for a rigid scene.",
    )
    appearance_time: bool | Literal["auto"] = Field(
        "auto",
        description="A rigid geometry whose albedo changes with time (space-time planes on "
        "the appearance grid only; time_nodes as a dynamic field's): what the camera sees of "
        "a fixed surface changing over the clip (its light, its exposure, the tissue's small "
        "motions). auto: on for a rigid TensoRF field. Real Hamlyn rectified01, all 196 "
        "frames, 1500 steps: held-out PSNR 31.4 dB against 20.9 rigid; the sinus window 21.9 "
        "against 17.0; the bench colon 27.9 against 27.6 with the same depth.",
    )
    change_weight: float = Field(
        0.001,
        ge=0,
        description="A dynamic field: weight of the penalty on its change's steps between time "
        "nodes (the scene changes slowly). 0.01 and more kept a tint that changes over a clip "
        "out of the field.",
    )
    time_nodes: int = Field(
        0,
        ge=0,
        description="Nodes along time of the space-time planes; 0: one per two frames, 4 to "
        "64 (a held-out frame then lies between nodes its neighbours fitted).",
    )
    warp: bool | Literal["auto"] = Field(
        "auto",
        description="Warp the grid per axis: linear around the camera path, logarithmic "
        "beyond, so cells grow with the distance to the cameras. auto: warp only when the "
        "cameras saw their surface near their path (warp_min_inside of the SfM points in the "
        "linear core); a scope that barely moves and looks far would lose what it saw.",
    )
    warp_min_inside: float = Field(
        0.5,
        ge=0,
        le=1,
        description="auto: warp when at least this share of the SfM points lies in the core.",
    )
    warp_core_pad: float = Field(
        1.5, ge=0, description="Linear core: the camera path's box grown by this many radii."
    )
    warp_soft: float = Field(
        2.0, gt=0, description="Beyond the core, cells double in size every ~this many radii."
    )
    color_hidden: int = Field(64, ge=8, description="Hidden width of the albedo head.")
    view_dependent: bool = Field(
        False,
        description="Feed the encoded view direction to the colour head (off: the albedo is "
        "view-independent, as the near-light model wants).",
    )
    dir_bands: int = Field(4, ge=0, description="Frequency bands of the view direction.")
    density_bias: float = Field(
        -5.0,
        description="Added to the raw density before the softplus (negative: starts nearly "
        "empty; -5 starts as a faint fog that the first hundred steps resolve).",
    )
    density_scale: float = Field(
        25.0, gt=0, description="Multiplies the softplus density (per scene unit = one radius)."
    )


class ShadingConfig(_Section):
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
    exposure: bool = Field(
        False,
        description="Learn a per-frame exposure (log gain, zero-mean over the training "
        "frames); held-out frames have none and are rendered at the mean (0).",
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


class SamplingConfig(_Section):
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
    chunk: int = Field(8192, ge=256, description="Rays per chunk when rendering whole images.")
    proposal: bool = Field(
        True,
        description="two_pass, training: the first pass reads a coarse copy of the density on "
        "a dense grid (nerf/proposal.py), refreshed as training goes, instead of the field.",
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


class LossConfig(_Section):
    """L = L_photo + l1 L_prior + l2 L_smooth + l3 L_geo (seed §3.5); each term can be off."""

    photo: bool = Field(True, description="L_photo: masked L2 on pixel colours.")
    prior: bool = Field(True, description="L_prior: the anatomical prior terms.")
    smooth: bool = Field(True, description="L_smooth: edge-aware depth smoothness on patches.")
    geo: bool = Field(True, description="L_geo: depth consistency between adjacent frames.")
    saturation: float = Field(
        0.98,
        gt=0,
        description="Pixel channels at or above this (0..1) are clipped: L_photo only penalises "
        "renderings darker than them (>1: off).",
    )
    photo_trim: float = Field(
        0.0,
        ge=0,
        lt=1,
        description="Leave this fraction of each batch's largest photometric residuals out of "
        "L_photo (robustness to highlights the masks missed; 0: plain masked L2).",
    )
    photo_weight: float = Field(
        1.0,
        gt=0,
        description="Weight of L_photo (the seed's 1). With Adam, raising it is lowering every "
        "other term at once.",
    )
    lambda_prior: float = Field(0.1, ge=0, description="lambda_1.")
    lambda_smooth: float = Field(
        0.01,
        ge=0,
        description="lambda_2 (the seed: 0.05, in the paper preset). A gradient penalty pulls a "
        "tube's walls towards the image plane: at 0.05 the 60-frame colon's field came out 4% "
        "short and its mesh 8.9% of the radius off; at 0.01, 7.2% (docs/experiments.md).",
    )
    lambda_geo: float = Field(0.01, ge=0, description="lambda_3.")
    prior_start: float = Field(
        10.0, ge=1, description="Coarse to fine: lambda_1 starts at this multiple and decays."
    )
    prior_decay: float = Field(
        0.5, gt=0, le=1, description="Fraction of training over which lambda_1 decays to itself."
    )
    core_weight: float = Field(1.0, ge=0, description="Prior: density in the lumen core.")
    core_fraction: float = Field(
        0.5,
        gt=0,
        lt=1,
        description="Core = wall shrunk to this, or less where the SfM points lie inside it "
        "(centerline.core_share).",
    )
    core_reach: float = Field(
        4.0,
        gt=0,
        description="The core penalty applies within this many radii of the camera (the tube "
        "follows the camera path; far ahead of it, it is a straight guess).",
    )
    wall_weight: float = Field(
        0.05, ge=0, description="Prior: attraction of the surface to the estimated wall."
    )
    wall_tolerance: float = Field(
        0.5, ge=0, description="Relative depth error to the prior's wall tolerated for free."
    )
    normal_weight: float = Field(
        0.01, ge=0, description="Prior: variance of the normals within each patch."
    )
    smooth_order: Literal[1, 2] = Field(
        1, description="Smoothness on depth gradients (1) or second differences (2)."
    )
    edge_scale: float = Field(10.0, ge=0, description="Edge-aware weight exp(-scale |grad I|).")
    patch_size: int = Field(4, ge=2, description="Rays are drawn as patches of this size.")
    patch_fraction: float = Field(
        0.5, ge=0, le=1, description="Share of each batch drawn as patches (rest: single rays)."
    )
    distortion_weight: float = Field(
        0.0,
        ge=0,
        description="Distortion loss (Mip-NeRF 360): concentrates each ray's weight on one "
        "surface instead of a semi-transparent ramp in front of it (0: off).",
    )
    opacity_weight: float = Field(
        0.2,
        ge=0,
        description="Opacity: (1 - opacity)^2 on the usable pixels' rays when there is no lumen "
        "prior (every ray of a scope meets tissue within the rays' reach; where the images say "
        "it is dark, the near-light model puts that tissue far instead of leaving the ray "
        "empty). A tube or cavity prior asks it of the rays that meet its wall already. "
        "endo.mp4 --config fast: lens pixels without depth 51% -> 6% (three seeds 5.6-7.4%), "
        "held-out PSNR 18.7 -> 19.0-19.1 dB. 0: off.",
    )
    geo_patches: int = Field(
        8, ge=0, description="Patches per step warped into the next frame for L_geo."
    )
    sparse_weight: float = Field(
        0.1,
        ge=0,
        description="Depth at the SfM points (DS-NeRF; not in the seed): Huber on the relative "
        "depth error of rays through the tracked pixels of the training frames. It pins the "
        "scale the photometric loss leaves free: 60-frame colon mesh 6.7-7.5% of the radius "
        "off without it, 4.3-4.6% with it, two seeds (0: off).",
    )
    sparse_rays: int = Field(256, ge=1, description="SfM-point rays per step.")
    sparse_min_track: int = Field(
        3, ge=2, description="Use points seen in at least this many images."
    )
    sparse_max_error: float = Field(
        2.0, gt=0, description="Use points with a mean reprojection error up to this (px)."
    )
    sparse_refine: bool = Field(
        True,
        description="Move each SfM point along its ray to where a 7x7 patch looks most alike in "
        "the training frames near its track (multi-view correlation) before its depth is used: "
        "bench colon 28% -> 21% of the tracked pixels over 5% off the truth; three NeRF seeds "
        "AbsRel 0.0320-0.0328, Chamfer 3.82-4.10%, off-seen 9.7-11.3% against 0.0340-0.0344, "
        "4.27-4.56%, 11.3-12.0% without; C3VD and the bench cavity the same.",
    )
    sparse_lens_share: float = Field(
        0.9,
        gt=0,
        description="With an estimated lens: follow the depth of the SfM points seen within "
        "this share of the radius its features reached (poses' fitted_radius_px). Near that "
        "edge the tracks pin the lens least, and the points' depth carries its error (C3VD's "
        "outer ring: 10-56% too far against the panel). C3VD 0.973 / 0.105 at 0.9, 0.972 / "
        "0.109 at 0.8, against 0.969 / 0.115 at 1 (all); the barrel colon whose estimated "
        "model is its true one: AbsRel 0.0343 against 0.0337 (two seeds). A given lens: every "
        "point.",
    )
    stereo_weight: float = Field(
        0.1,
        ge=0,
        description="Depth from a stereo rig (the ingest stage's stereo/, metric): the same "
        "Huber as the SfM points' on rays through matched pixels of the training frames. It "
        "gives a still camera depth and every frame its metric scale (0: off).",
    )
    stereo_rays: int = Field(512, ge=1, description="Stereo-depth rays per step.")
    stereo_spread: Annotated[float, Field(ge=0)] | Literal["auto"] = Field(
        "auto",
        description="On the stereo rays, the weight of each ray's density spread about the "
        "measured depth (the sum of its render weights times the squared relative distance "
        "from it, as DS-NeRF's depth loss): a surface at the depth, not a haze averaging to "
        "it. auto: 1 for a camera that stands still, 0 for one that moves. Seen from one "
        "place, nothing but the rig says where along a ray the density sits: without it a "
        "still stereo cavity's field was a haze 2.7% behind the rig's depth (AbsRel 0.079 "
        "unscaled, its matcher's 0.009), with it 0.010. A moving camera's parallax gathers "
        "the density itself, and at 1 its depth came out worse (docs/experiments.md).",
    )

    def spread_weight(self, still: bool) -> float:
        """stereo_spread as a number: auto resolved for a still or a moving camera."""
        if self.stereo_spread == "auto":
            return 1.0 if still else 0.0
        return float(self.stereo_spread)

    stereo_per_frame: int = Field(
        4096, ge=1, description="Matched pixels drawn once per training frame (a fixed draw)."
    )
    depth_prior_weight: float = Field(
        0.1,
        ge=0,
        description="Depth maps the user made elsewhere (`--depth-prior`, the ingest stage's "
        "depth_prior/; relative): each frame's map fitted to the rendered depth by a "
        "least-squares scale and shift, then a Huber on the residual (scale-and-shift "
        "invariant, as MiDaS's loss). Shapes each frame's depth, never its scale. Nothing "
        "without --depth-prior (0: off).",
    )
    shading_prior_weight: float = Field(
        0.0,
        ge=0,
        description="A camera that stands still with nothing else to place depth (no stereo, "
        "no depth given, no --depth-prior): each frame's depth from the light's fall-off "
        "(range = 1/sqrt(the blurred linear brightness), nerf.shading_depth), followed as "
        "the depth prior is, up to a scale and shift per frame. Off by default: at 0.1 the "
        "pulled wall's depth only matched the shading map itself, and the real cutting "
        "clip's rays spread over no one surface on 59% of the pixels against 27% "
        "(docs/experiments.md) (0: off).",
    )
    depth_prior_frames: int = Field(
        4, ge=1, description="Frames per step for the depth prior (a scale and shift each)."
    )
    depth_prior_rays: int = Field(128, ge=8, description="Depth-prior rays per frame per step.")
    depth_prior_per_frame: int = Field(
        4096, ge=8, description="Prior pixels drawn once per training frame (a fixed draw)."
    )
    sparse_min_angle: float = Field(
        0.0,
        ge=0,
        description="Use points seen under at least this angle between two of their cameras "
        "(degrees; 0: all): a point seen down the direction of travel has its depth badly "
        "determined, and short. At 3: C3VD 0.971 / 0.108 and 0.971 / 0.109 against 0.968 / 0.113 "
        "and 0.969 / 0.113 (two seeds); the bench colon the same within its seeds' spread; the "
        "1,500-frame withdrawal a little worse (AbsRel 0.0351 against 0.0347, Chamfer 3.12 "
        "against 3.06%), so off by default; at 5 the colon's scale goes (AbsRel 0.0365).",
    )


class TrainConfig(_Section):
    """Optimisation, schedule, hold-out, checkpoints."""

    steps: int = Field(1500, ge=1, description="Optimisation steps (at most).")
    time_budget_s: float | None = Field(
        600.0,
        gt=0,
        description="A last resort against a slow or loaded machine (s): past it the schedules "
        "run on max(step / steps, time / budget) and training ends when either is done, so the "
        "result then depends on the machine; the log, summary and report say at which step "
        "(null: all steps, always).",
    )
    batch_rays: int = Field(1024, ge=16, description="Rays per step.")
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
    fit_frames: int = Field(
        3,
        ge=0,
        description="Training frames rendered after training to measure the fit (spread over "
        "the sequence; 0: none, and no word on whether the field learned its images).",
    )


class PoseRefineConfig(_Section):
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


class FarViewConfig(_Section):
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
