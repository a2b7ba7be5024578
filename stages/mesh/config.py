"""The mesh stage's settings (06_mesh): how the surface is built, cleaned and evaluated."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from endopipe.pipeline.stage import StageConfig


class MeshConfig(StageConfig):
    method: Literal["tsdf", "marching_cubes"] = Field(
        "tsdf",
        description="tsdf: fuse the depth maps of 05_depth (open3d); marching_cubes: iso-surface "
        "of the NeRF density in the prior's band around the lumen wall.",
    )
    voxels_per_radius: float = Field(
        64.0, gt=0, description="TSDF voxel size = lumen radius (the prior's) / this."
    )
    frame: int | None = Field(
        None,
        ge=0,
        description="A scene that moves (a dynamic field): the frame whose surface is meshed "
        "(tsdf: that frame's depth alone; fusing every time would average the motion). None: "
        "the first registered frame.",
    )
    times: int = Field(
        4,
        ge=0,
        description="A scene that moves: also a surface at this many frames spread evenly over "
        "the clip (06_mesh/times/mesh_<frame>.ply, tsdf), so the report shows it moving. 0: "
        "none.",
    )
    voxel_size: float | None = Field(
        None, gt=0, description="TSDF voxel size in cameras.json units; overrides the above."
    )
    sdf_trunc_voxels: float = Field(4.0, gt=1, description="TSDF truncation distance, in voxels.")
    depth_trunc: float | None = Field(
        None,
        gt=0,
        description="Ignore depths beyond this (cameras.json units); also the depth limit of "
        "the evaluation crop and of the marching-cubes grid. None: from the data (below).",
    )
    depth_trunc_percentile: float = Field(
        95.0,
        gt=0,
        le=100,
        description="When depth_trunc is None: this percentile of all valid depths.",
    )
    min_opacity: float = Field(
        0.5,
        ge=0,
        le=1,
        description="Drop pixels whose 05_depth opacity is below this (when opacity maps exist).",
    )
    min_observations: int = Field(
        1, ge=1, description="TSDF: frames that must observe a voxel for it to be surface."
    )
    colour: bool = Field(True, description="TSDF: vertex colours from the ingest frames.")
    mc_voxels_per_radius: float = Field(
        32.0, gt=0, description="Marching cubes: grid spacing = lumen radius / this."
    )
    band: float = Field(
        0.6,
        gt=0,
        description="Marching cubes: evaluate the density where |prior signed distance| < "
        "band x local radius (elsewhere nothing is extracted).",
    )
    density_level: float | None = Field(
        None,
        gt=0,
        description="Marching cubes: iso-level of the density, per lumen radius (the NeRF's "
        "scene units; sigma in world units = level / radius). None: calibrated from the field, "
        "the density at its rendered surface (a fixed level sits in front of it).",
    )
    cull_unseen: bool = Field(
        True,
        description="Marching cubes: keep only faces that a registered camera's pixel ray hits "
        "first, on their lumen side (drops surface behind the wall and never-seen parts).",
    )
    cull_dilate: int = Field(
        1, ge=0, description="Marching cubes: grow the seen faces by this many rings (no holes)."
    )
    device: Literal["auto", "cpu", "cuda"] = Field(
        "auto", description="Marching cubes: where the NeRF density is evaluated."
    )
    chunk: int = Field(
        1 << 18, ge=1024, description="Marching cubes: points per density evaluation."
    )
    min_component_fraction: float = Field(
        0.05,
        ge=0,
        le=1,
        description="Drop connected components with fewer faces than this x the largest's.",
    )
    min_component_diameter: float = Field(
        0.5,
        ge=0,
        description="Drop connected components whose bounding-box diagonal is under this many "
        "lumen radii (floaters).",
    )
    smooth_iterations: int = Field(5, ge=0, description="Taubin smoothing steps (0: none).")
    taubin_lambda: float = Field(0.5, gt=0, lt=1, description="Taubin smoothing lambda.")
    taubin_mu: float = Field(-0.53, lt=0, gt=-1, description="Taubin smoothing mu (negative).")
    export_obj: bool = Field(False, description="Also write mesh.obj (same frame and units).")
    evaluate: bool = Field(
        True, description="Compare with the case's gt/mesh.ply when it exists (metrics.json)."
    )
    eval_samples: int = Field(
        200_000, ge=1000, description="Points sampled on each surface for the evaluation."
    )
    eval_occlusion: bool = Field(
        True,
        description="Evaluation crop: GT surface counts only where it is the first hit from a "
        "camera (hidden behind folds: not asked for). Off: everything in the frustums.",
    )
    fscore_threshold: float = Field(
        1.0, gt=0, description="F-score distance threshold, in GT units (mm)."
    )
    fscore_threshold_pct_radius: float | None = Field(
        None,
        gt=0,
        description="When set: the F-score threshold is this % of the mean lumen radius instead.",
    )
