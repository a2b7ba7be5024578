"""The nerf config's field section: the geometry (density or signed distance) and its
encoding (TensoRF grid, hash grid or positional MLP); kept apart from config.py because the
field model reads it alone."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from endopipe.stages.nerf.config_section import ConfigSection


class TensorfConfig(ConfigSection):
    """TensoRF vector-matrix grid (the CPU default)."""

    density_components: int = Field(
        16,
        ge=1,
        description="VM components per plane for density (8 underfits the colon's folds: mesh "
        "7.2% of the radius off vs 6.8% at 16, two seeds; 32: no better, slower).",
    )
    appearance_components: Annotated[int, Field(ge=1)] | Literal["auto"] = Field(
        "auto",
        description="VM components per plane for the albedo features. auto: 32, and 16 for a "
        "field whose geometry changes with time (a still camera's, which learns by steps: "
        "the cutting clip at 2x the steps (`train.still_steps`) in the same time, held-out "
        "30.62 / 30.63 dB against 30.30 / 30.25 at 32, seeds 0 / 1).",
    )
    appearance_dim: int = Field(27, ge=1, description="Albedo feature size fed to the colour MLP.")

    def albedo_components(self, dynamic: bool) -> int:
        """appearance_components as a number (auto resolved for a dynamic field or not)."""
        if self.appearance_components != "auto":
            return int(self.appearance_components)
        return 16 if dynamic else 32

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


class HashgridConfig(ConfigSection):
    """Instant-NGP hash grid in pure PyTorch (for GPU users; slow on a CPU)."""

    levels: int = Field(16, ge=1, description="Resolution levels.")
    features: int = Field(2, ge=1, description="Features per level.")
    log2_size: int = Field(19, ge=8, le=24, description="log2 of the hash table rows per level.")
    base_res: int = Field(16, ge=2, description="Coarsest level's resolution.")
    max_res: int = Field(1024, ge=4, description="Finest level's resolution.")
    hidden: int = Field(64, ge=8, description="Width of the density MLP.")
    geo_features: int = Field(15, ge=1, description="Features passed from density to colour MLP.")


class PositionalConfig(ConfigSection):
    """The paper's coordinate MLP (seed §3.1, §4.3): ReLU MLP over sinusoidal encodings."""

    depth: int = Field(8, ge=2, description="Fully connected layers.")
    width: int = Field(256, ge=8, description="Hidden units per layer.")
    skip: int = Field(4, ge=0, description="Layer that gets the encoded input again (0: none).")
    pos_bands: int = Field(10, ge=0, description="Frequency bands for positions.")


class SdfConfig(ConfigSection):
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


class FieldConfig(ConfigSection):
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
        "motions). auto: on for a rigid TensoRF field shaped by a lumen prior, and for a moving "
        "camera with no prior (with the warped grid and no n.l; a still camera without one: "
        "off). Real Hamlyn rectified01, all 196 frames, 1500 steps: held-out PSNR 31.4 dB "
        "against 20.9 rigid; the bench colon 27.9 against 27.6 with the same depth; the sinus "
        "window 23.5 against 20.0 with the field's depth 0.086 either way.",
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
    warp: bool | Literal["auto", "frustum"] = Field(
        "auto",
        description="Warp the grid per axis: linear around the camera path, logarithmic "
        "beyond, so cells grow with the distance to the cameras. auto: warp only when the "
        "cameras saw their surface near their path (warp_min_inside of the SfM points in the "
        "linear core), or when no lumen prior bounds the scene (its reach past every point "
        "sized an unwarped grid too coarse); a scope that barely moves and looks far would "
        "lose what it saw. frustum: the grid over the first camera's view, in image "
        "coordinates and log depth (auto for a still camera over tissue that moves: its "
        "planes lie on the pixels at every depth; docs/method.md).",
    )
    frustum_depth_nodes: float = Field(
        0.25,
        gt=0,
        le=1,
        description="The frustum grid's nodes along log depth, as a share of those along the "
        "image's wider side: a still camera sees one surface a pixel, and fine depth cells "
        "only enlarge the planes every step updates (the cutting clip at 0.25: held-out "
        "33.05 dB against 32.92 at 1, a step 92 ms against 104).",
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
