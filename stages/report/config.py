"""The report stage's config: what the page includes and how heavy it may get."""

from __future__ import annotations

from pydantic import Field

from endopipe.pipeline.stage import StageConfig


class ReportConfig(StageConfig):
    title: str | None = Field(
        None, description="Page title; default 'endopipe report: <case name>'."
    )
    max_preview_frames: int = Field(
        4,
        ge=0,
        le=16,
        description="Frames in the depth preview (RGB | depth | GT depth | abs-rel error), "
        "evenly spaced over the sequence.",
    )
    preview_width: int = Field(
        320, ge=64, le=1024, description="Width in pixels of a preview tile (downscale only)."
    )
    error_max: float = Field(
        0.25, gt=0, description="Abs-rel error at the top of the error maps' colour scale."
    )
    include_video: bool = Field(
        True, description="Inline 05_depth/preview.mp4 when it is at most max_video_mb."
    )
    max_video_mb: float = Field(4.0, ge=0, description="Largest preview video inlined (MB).")
    include_mesh_viewer: bool = Field(
        True,
        description="Interactive 3D viewer of the mesh: trimesh's three.js page, which carries "
        "three.js inside it (no network), in an iframe. Static views are always included.",
    )
    mesh_max_faces: int = Field(
        20_000,
        ge=100,
        description="Decimate the mesh to at most this many faces for the viewer and the "
        "static views (keeps the page a few MB).",
    )
    mesh_views: int = Field(
        3, ge=0, le=3, description="Static renderings of the mesh: side, top, end-on."
    )
    jpeg_quality: int = Field(88, ge=30, le=100, description="JPEG quality of photo-like images.")
    max_runs: int = Field(5, ge=0, description="Most recent runs listed from <case>/runs/.")
