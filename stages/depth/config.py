"""The depth stage's settings: which renderer, the baked surface's resolution, the preview."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from endopipe.pipeline.stage import StageConfig


class DepthConfig(StageConfig):
    renderer: Literal["baked", "field"] = Field(
        "baked",
        description="baked: ray-cast an iso-surface baked once from the field's density (fast); "
        "field: volume-render the trained field at every sample (exact expected depth, slow).",
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
        "of the wall, a ray grazing a fold's rim). Applies to rays the baked surface misses, "
        "and to all with renderer field. None: any spread.",
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
    preview: bool = Field(True, description="Write preview.mp4 (RGB | depth | error).")
    preview_fps: int = Field(10, ge=1, description="Frame rate of preview.mp4.")
    colour: bool = Field(
        True, description="Render colour too (needed for PSNR/SSIM on held-out frames)."
    )
