"""The mesh: its accuracy against the ground-truth surface, how it was evaluated and built,
by distance to the cameras, and the mesh itself (sections/mesh_views.py)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from endopipe.stages.mesh.metrics_file import MeshMetrics
from endopipe.stages.report.kit import not_available, render
from endopipe.stages.report.load import CaseData
from endopipe.stages.report.sections.common import ReportInfo, number
from endopipe.stages.report.sections.mesh_views import VIEWER_NOTE, mesh_views

if TYPE_CHECKING:
    from endopipe.stages.mesh.metrics_file import DistanceBand
    from endopipe.stages.mesh.summary import MeshSummary

METHODS = {
    "tsdf": "TSDF fusion of the depth maps",
    "marching_cubes": "marching cubes on the NeRF's density",
}


@dataclass(frozen=True)
class Surface:
    """How the surface was made: metrics.json's figures, else the summary's."""

    method: str
    vertices: int | None  # None: not known (the row is left out)
    faces: int | None
    voxel_size: float | None
    sdf_trunc: float | None
    depth_trunc: float | None
    frames_used: int | None
    build_s: float | None
    clean_s: float | None

    @property
    def method_note(self) -> str:
        return METHODS.get(self.method, "")

    @classmethod
    def of(cls, m: MeshMetrics, s: MeshSummary | None) -> Surface:
        def either(value: Any, fallback: Any) -> Any:
            return value if value is not None else fallback

        return cls(
            method=m.method or (s.method if s else "") or "",
            vertices=either(m.vertices, s.vertices if s else None),
            faces=either(m.faces, s.faces if s else None),
            voxel_size=either(m.voxel_size, s.voxel_size if s else None),
            sdf_trunc=m.sdf_trunc,
            depth_trunc=either(m.depth_trunc, s.depth_trunc if s else None),
            frames_used=either(m.frames_used, s.frames_used if s else None),
            build_s=s.build_s if s else None,
            clean_s=s.clean_s if s else None,
        )


@dataclass(frozen=True)
class Band:
    """A row of by_camera_distance: surface between `lo` and `hi` from the nearest camera."""

    lo: float | None
    hi: float | None  # None: the open last band
    chamfer: float | None
    chamfer_pct_radius: float | None
    accuracy: float | None
    completeness: float | None
    gt_share_pct: float | None


def bands(rows: list[DistanceBand] | None) -> list[Band]:
    """metrics.json's by_camera_distance as the table's rows."""
    return [
        Band(
            b.from_,
            b.to,
            b.chamfer,
            b.chamfer_pct_radius,
            b.accuracy,
            b.completeness,
            100.0 * b.gt_share if b.gt_share is not None else None,
        )
        for b in rows or []
    ]


def crop_words(crop: str) -> str:
    """metrics.json's crop, in the page's words."""
    return crop.replace("gt surface", "ground-truth surface").replace(" within crop_max_depth", "")


def others(m: MeshMetrics) -> list[tuple[str, Any, str]]:
    """metrics.json's keys the model does not name (written by another version), each a
    number or words: listed under "other values", so nothing the stage wrote is dropped
    without a word."""
    extra = m.model_extra or {}
    return [
        (key.replace("_", " "), v, key)
        for key, v in extra.items()
        if number(v) is not None or isinstance(v, str)
    ]


def section_mesh(data: CaseData, info: ReportInfo) -> str | None:
    if data.mesh is None:
        if "mesh" in data.view_errors:
            info.mesh_viewer = "none"
            return not_available(f"06_mesh unreadable: {data.view_errors['mesh']}")
        return None
    mm = data.mesh_metrics
    m = mm if mm is not None else MeshMetrics()
    s = data.mesh_summary
    evaluated = m.evaluated
    gt_units = str(getattr(data.ground_truth(), "units", "") or "mm") if evaluated else ""
    tau, radius = m.threshold, m.mean_radius
    not_evaluated = None
    if mm is not None and not mm.evaluated:
        not_evaluated = mm.reason or "no reason given"
    no_metrics = (
        "no ground-truth surface to compare with"
        if info.gt_kind == "none"
        else "06_mesh/metrics.json is missing"
    )
    return render(
        "sections/mesh.html.j2",
        has_metrics=mm is not None,
        evaluated=evaluated,
        not_evaluated=not_evaluated,
        no_metrics=no_metrics,
        u=gt_units,
        m=m,
        at=f"{tau:g} {gt_units}" if tau is not None else "the threshold",
        crop=crop_words(m.crop) if m.crop else "",
        surface=Surface.of(m, s),
        units=str((s.units if s else "") or data.units),
        others=others(m),
        bands=bands(m.by_camera_distance) if evaluated else [],
        radius=radius if radius is not None and radius > 0 else None,
        views=mesh_views(data, info),
        viewer_note=VIEWER_NOTE,
    )
