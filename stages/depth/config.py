"""The depth stage's settings: which renderer, the baked surface's resolution, the preview."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from endopipe.pipeline.stage import StageConfig


class DepthConfig(StageConfig):
    renderer: Literal["baked", "field"] = Field(
        "baked",
        description="baked: ray-cast an iso-surface baked once from the field's density (fast); "
        "field: volume-render the trained field at every sample (slow; its depth: field_depth).",
    )
    field_depth: Literal["auto", "median", "expected"] = Field(
        "auto",
        description="A volume-rendered ray's depth (renderer field, every frame of a field that "
        "changes with time, the rays a baked surface misses when the field answers them): "
        "expected, its weights' mean, which measured depth (SfM points, stereo, given depth) "
        "trains; median, where half its weight lies nearer, which haze in front of the wall "
        "does not pull off it. auto: expected where measured depth trained the field, median "
        "where nothing did. Median-scaled AbsRel, every 10th frame: the pulled wall seen from "
        "one place 0.0585 against 0.0648; the same with its depth/ 0.040 against 0.036, and "
        "in mm 0.095 against 0.043.",
    )
    dynamic_samples: tuple[int, int] = Field(
        (16, 8),
        description="A field that changes with time has no one surface to bake, so every frame "
        "is volume-rendered: its coarse and fine samples per ray (the nerf stage renders "
        "held-out frames with 32, 16). Fewer smear a surface's weights over no one depth "
        "(scripts/depth_samples.py): the pulled wall keeps depth on 73.6% of its tissue at "
        "16 + 8, 80.1% at 20 + 10, 87.1% at 24 + 12 (AbsRel 0.0572 / 0.0586 / 0.0558); "
        "EndoNeRF's cutting clip lacks depth on 26.7% / 19.4% / 15.9% of its pixels, but "
        "at 24 + 12 its depth stage takes 1.48 s a frame against 0.81, and the clip 10.0 min "
        "from nothing against 7.9.",
    )
    anchor: Literal["auto", "points", "off"] = Field(
        "auto",
        description="Hold each depth map to what was measured (depth/anchor.py): auto: the "
        "rig's stereo depth where it matched (the poses metric), the field's depth corrected "
        "to it elsewhere (real Hamlyn: 0.032 against the release's depth on every pixel, the "
        "field alone 0.053, the matcher alone 0.032 on 98%); without a rig, the field's depth "
        "as it is. points: also, without a rig, the field's depth corrected towards the SfM "
        "points where they disagree with it beyond their noise: the sinus window 0.098 against "
        "0.108 at the authors' points, the bench colon 0.0349 against 0.0347, but C3VD 0.950 / "
        "0.149 against 0.967 / 0.114 (its outer ring's points carry the lens's error). off: "
        "the field's depth as it is.",
    )

    @field_validator("anchor", mode="before")
    @classmethod
    def _yaml_off(cls, value: object) -> object:
        """`--set depth.anchor=off` reaches here as YAML's false."""
        return {False: "off", True: "auto"}.get(value, value) if isinstance(value, bool) else value

    anchor_sigma_stereo: float = Field(
        0.025,
        gt=0,
        description="How far a stereo pixel's correction reaches into the unmatched ones "
        "(Gaussian sigma, a share of the image width).",
    )
    anchor_sigma_points: float = Field(
        0.05,
        gt=0,
        description="... an SfM point's (sparser: a wider reach).",
    )
    device: Literal["auto", "cpu", "cuda"] = Field(
        "auto",
        description="Where the field is evaluated (baking, volume rendering): auto is CUDA when "
        "torch sees one. Ray casting the baked surfaces runs on the CPU (Embree).",
    )
    bake_voxels_per_radius: int = Field(
        24, ge=4, le=256, description="Baked surface: grid nodes per lumen radius."
    )
    bake_density_level: float | None = Field(
        None,
        gt=0,
        description="Baked surface: density iso-level, per lumen radius (None: calibrated so "
        "that the baked surface passes through the field's rendered surface).",
    )
    min_opacity: float = Field(
        0.5,
        gt=0,
        le=1,
        description="A ray whose rendered opacity is under this found no surface: its depth is "
        "0 (unknown), not a guess.",
    )
    max_spread: float | None = Field(
        0.15,
        gt=0,
        description="A ray the field puts on no one surface gets no depth (0, unknown): the middle "
        "half of its rendered weight spans more than this fraction of its depth (haze in front "
        "of the wall, a ray grazing a fold's rim); with far: baked, of the weight its density "
        "ramp gives (far_levels). Applies to rays the baked surface misses, and to all with "
        "renderer field. None: any spread.",
    )
    bake_near: Literal["auto", "on", "off"] = Field(
        "auto",
        description="Baked surface: an iso-surface of the density up to 2.5 lumen radii from "
        "each camera, answering the rays it meets before the far bake. auto: on with a lumen "
        "prior, off without one (a free scene: no wall to level the iso-surface on, so it "
        "catches the haze in front of the surface; the far bake's weight quartiles land where "
        "the field renders. Sinus window w000 at the authors' points, 24 frames, any spread "
        "(scripts/bake_choice.py): 0.1102 with it, 0.0882 without, the volume-rendered field "
        "0.0918 at 4.7 s a map against 0.17; its 95 frames as run: 0.0844 against 0.1116).",
    )
    free_max_spread: float | None = Field(
        0.3,
        gt=0,
        description="max_spread of the baked read-out in a free scene (no lumen prior; a "
        "volume-rendered field keeps max_spread): its far bake's ramps are "
        "wider for the grid's cells, warped large away from the cameras, not for haze (sinus "
        "window w000, 24 frames: AbsRel 0.0817 on 33% of the view at 0.15, 0.0834 on 82% at "
        "0.3, 0.0882 on all). None: any spread.",
    )
    bake_min_component: float = Field(
        0.5,
        ge=0,
        description="Baked surface: drop connected pieces less than this many lumen radii across "
        "(floaters; mesh.min_component_diameter drops them from the mesh). 0: keep all.",
    )
    fill: bool = Field(
        False,
        description="Give rays that found no surface the depth where they leave the lumen "
        "prior's wall instead of 0 (a guess from the prior, not an observation; the mesh never "
        "fuses them: their opacity stays under min_opacity).",
    )
    far: Literal["baked", "field"] = Field(
        "baked",
        description="Rays the baked surface misses (down the lumen past its reach, through a hole "
        "in it): baked: ray-cast a coarser bake of everything the cameras see, with the spread "
        "judged from how far the density takes to climb to the surface (C3VD: 2 ray casts "
        "instead of volume-rendering a fifth of the rays, 500 ms a map); field: volume-render "
        "the field on them (the exact expected depth and weight spread).",
    )
    far_max_nodes: int = Field(
        16_000_000,
        ge=1000,
        description="Far bake: at most this many grid nodes; it samples the field at the field's "
        "own resolution (its grid's nodes) up to this (memory, baking time).",
    )
    far_levels: list[float] = Field(
        [0.1, 0.5],
        min_length=1,
        description="Far bake: the fractions of the surface level (each under 1) whose "
        "iso-surfaces, with the surface's, outline each ray's density ramp: its weight's "
        "quartiles give the depth and the spread (max_spread).",
    )
    far_faint: Literal["unknown", "field"] = Field(
        "unknown",
        description="Far bake: a ray whose density stays under the second level (faint haze, or "
        "the thick faint wall at the end of a long lumen): unknown: no depth; field: "
        "volume-render it. The field finds a surface on 3% of them on the laparoscopy video "
        "(a tenth of its pixels: 167 ms a map instead of 30) and on 85% on the bench colon "
        "(0.3% of its pixels; coverage 0.996 instead of 0.993, Chamfer 4.40% instead of 4.36%).",
    )
    support_frames: int = Field(
        6,
        ge=0,
        description="Views maps: how many nearby frames each depth pixel is checked against "
        "(its surface point projected into them, their depth asked; 0: no views maps).",
    )
    support_tolerance: float = Field(
        0.05,
        gt=0.0,
        description="Views maps: a view agrees when its depth is within this share of the "
        "point's depth in it.",
    )
    seen_again_views: int = Field(
        2, ge=1, description="Views maps: agreeing views for a depth to count as seen again."
    )
    preview: bool = Field(True, description="Write preview.mp4 (RGB | depth | error).")
    preview_fps: int = Field(10, ge=1, description="Frame rate of preview.mp4.")
    colour: bool = Field(
        True, description="Render colour too (needed for PSNR/SSIM on held-out frames)."
    )
