"""06_mesh/metrics.json (docs/formats.md) as one model: the mesh stage writes it through
`MeshMetrics.write`, `MeshView.metrics` reads it back, and the report reads its fields."""

from __future__ import annotations

from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field

from endopipe.stages.metrics.files import MetricsFile


class DistanceBand(BaseModel):
    """One row of by_camera_distance: the surface whose nearest camera centre lies between
    `from` and `to` (written under those keys; `from` is a Python keyword, hence `from_`)."""

    model_config = ConfigDict(extra="allow", populate_by_name=True)

    from_: float = Field(alias="from")
    to: float | None = None  # the open last band is written as null
    accuracy: float | None = None
    completeness: float | None = None
    chamfer: float | None = None
    chamfer_pct_radius: float | None = None
    est_share: float | None = None
    gt_share: float | None = None


class MeshMetrics(MetricsFile):
    """metrics.json as the mesh stage writes it: flat keys, JSON null for inf / nan. The
    evaluation's keys are there when `evaluated`, else `reason` says why not; how the surface
    was made follows. Keys another version wrote are kept (`model_extra`)."""

    model_config = ConfigDict(extra="allow")

    evaluated: bool = False
    # against the ground-truth mesh (stages.surface.evaluate), in GT units
    chamfer: float | None = None
    chamfer_pct_radius: float | None = None
    accuracy: float | None = None
    completeness: float | None = None
    accuracy_median: float | None = None
    completeness_median: float | None = None
    precision: float | None = None
    recall: float | None = None
    fscore: float | None = None
    threshold: float | None = None
    gt_area_seen: float | None = None
    gt_points: int | None = None
    est_points: int | None = None
    off_seen_pct: float | None = None  # % of the mesh far from any surface a camera saw
    off_seen_threshold: float | None = None  # ... that far
    by_camera_distance: list[DistanceBand] | None = None
    aligned: str | None = None  # "gt_frame" | "rigid" (metric in its own frame) | "sim3"
    sim3_scale: float | None = None
    mean_radius: float | None = None
    crop_max_depth: float | None = None
    crop: str | None = None
    eval_s: float | None = None
    gt_kind: str | None = None
    reason: str | None = None  # why not evaluated
    # how the surface was made
    method: str | None = None
    vertices: int | None = None  # in mesh.ply, after clean-up
    faces: int | None = None
    raw_vertices: int | None = None  # as built, before clean-up
    raw_faces: int | None = None
    voxel_size: float | None = None
    sdf_trunc: float | None = None
    depth_trunc: float | None = None
    frames_used: int | None = None
    level: float | None = None
    band_nodes: int | None = None
    faces_extracted: int | None = None
    seen_fraction: float | None = None
    components_removed: int | None = None

    #: JSON values, the by_camera_distance bands under their keys (`from`)
    dump: ClassVar[dict[str, Any]] = {"mode": "json", "by_alias": True, "exclude_unset": True}
