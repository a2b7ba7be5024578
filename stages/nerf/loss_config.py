"""The nerf config's loss section: every term of the objective with its weight, the
measurements behind each default in its help."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from endopipe.stages.nerf.config_section import ConfigSection


class LossConfig(ConfigSection):
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
