"""The mesh: its accuracy against the ground-truth surface, how it was evaluated and built,
by distance to the cameras, and the mesh itself (sections/mesh_views.py)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from endopipe.stages.report.kit import not_available, render
from endopipe.stages.report.load import CaseData
from endopipe.stages.report.sections.common import ReportInfo, number
from endopipe.stages.report.sections.mesh_views import VIEWER_NOTE, mesh_views

if TYPE_CHECKING:
    from endopipe.stages.mesh.summary import MeshSummary
    from endopipe.stages.mesh.view import MeshMetrics

#: metrics.json / summary keys the mesh table shows in its own rows (anything else numeric is
#: listed under "other values", so nothing the stage wrote is dropped without a word).
MESH_SHOWN = {
    "evaluated", "reason", "gt_kind", "chamfer", "chamfer_pct_radius", "accuracy",
    "completeness", "accuracy_median", "completeness_median", "precision", "recall", "fscore",
    "threshold", "gt_area_seen", "gt_points", "est_points", "by_camera_distance", "aligned",
    "sim3_scale", "mean_radius", "crop_max_depth", "crop", "eval_s", "method", "vertices",
    "faces", "raw_vertices", "raw_faces", "voxel_size", "sdf_trunc", "depth_trunc",
    "frames_used", "level", "band_nodes", "faces_extracted", "seen_fraction",
    "components_removed", "units", "build_s", "clean_s", "off_seen_pct", "off_seen_threshold",
}  # fmt: skip
#: metrics.json's numbers the table shows (None where absent or not a number).
NUMBERS = (
    "chamfer", "chamfer_pct_radius", "accuracy", "accuracy_median", "completeness",
    "completeness_median", "fscore", "precision", "recall", "threshold", "off_seen_pct",
    "off_seen_threshold", "sim3_scale", "crop_max_depth", "gt_area_seen", "mean_radius", "eval_s",
)  # fmt: skip
COUNTS = ("est_points", "gt_points", "raw_vertices", "raw_faces", "components_removed")
METHODS = {
    "tsdf": "TSDF fusion of the depth maps",
    "marching_cubes": "marching cubes on the NeRF's density",
}


def count(value: Any) -> int | None:
    n = number(value)
    return int(n) if n is not None else None


@dataclass(frozen=True)
class Surface:
    """How the surface was made: metrics.json's figures, else the summary's."""

    method: str
    vertices: Any  # None: not known (the row is left out)
    faces: Any
    voxel_size: float | None
    sdf_trunc: float | None
    depth_trunc: float | None
    frames_used: Any
    build_s: float | None
    clean_s: float | None

    @property
    def method_note(self) -> str:
        return METHODS.get(self.method, "")

    @property
    def counts(self) -> tuple[int | None, int | None, int | None]:
        """Vertices, faces and frames used, as whole numbers (None: not a number)."""
        return count(self.vertices), count(self.faces), count(self.frames_used)

    @classmethod
    def of(cls, m: MeshMetrics, s: MeshSummary | None) -> Surface:
        def either(key: str, fallback: Any) -> Any:
            return m[key] if key in m else fallback

        return cls(
            method=str(m.get("method") or (s.method if s else "") or ""),
            vertices=either("vertices", s.vertices if s else None),
            faces=either("faces", s.faces if s else None),
            voxel_size=number(either("voxel_size", s.voxel_size if s else None)),
            sdf_trunc=number(m.get("sdf_trunc")),
            depth_trunc=number(either("depth_trunc", s.depth_trunc if s else None)),
            frames_used=either("frames_used", s.frames_used if s else None),
            build_s=s.build_s if s else None,
            clean_s=s.clean_s if s else None,
        )


@dataclass(frozen=True)
class Band:
    """A row of by_camera_distance: surface between `lo` and `hi` from the nearest camera."""

    lo: float | None
    hi: float | None  # None: the open last band
    chamfer: Any
    chamfer_pct_radius: Any
    accuracy: Any
    completeness: Any
    gt_share_pct: float | None


def bands(raw: Any) -> list[Band]:
    """metrics.json's by_camera_distance, rows that are not objects left out."""
    if not isinstance(raw, list):
        return []
    return [
        Band(
            b.get("from"),
            b.get("to"),
            b.get("chamfer"),
            b.get("chamfer_pct_radius"),
            b.get("accuracy"),
            b.get("completeness"),
            100.0 * b["gt_share"] if isinstance(b.get("gt_share"), float) else None,
        )
        for b in raw
        if isinstance(b, dict)
    ]


def crop_words(crop: str) -> str:
    """metrics.json's crop, in the page's words."""
    return crop.replace("gt surface", "ground-truth surface").replace(" within crop_max_depth", "")


def section_mesh(data: CaseData, info: ReportInfo) -> str | None:
    if data.mesh is None:
        if "mesh" in data.view_errors:
            info.mesh_viewer = "none"
            return not_available(f"06_mesh unreadable: {data.view_errors['mesh']}")
        return None
    mm = data.mesh_metrics
    m: MeshMetrics = mm or {}
    s = data.mesh_summary
    evaluated = bool(m.get("evaluated"))
    gt_units = str(getattr(data.ground_truth(), "units", "") or "mm") if evaluated else ""
    tau = number(m.get("threshold"))
    radius = number(m.get("mean_radius"))
    not_evaluated = None
    if m.get("evaluated") is False:
        not_evaluated = m.get("reason") or "no reason given"
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
        n={key: number(m.get(key)) for key in NUMBERS},
        c={key: count(m.get(key)) for key in COUNTS},
        has_gt_points=m.get("gt_points") is not None,
        at=f"{tau:g} {gt_units}" if tau is not None else "the threshold",
        aligned=str(m.get("aligned") or ""),
        crop=crop_words(str(m["crop"])) if m.get("crop") else "",
        surface=Surface.of(m, s),
        units=str((s.units if s else "") or data.units),
        others=[
            (key.replace("_", " "), v, key)
            for key, v in m.items()
            if key not in MESH_SHOWN and (number(v) is not None or isinstance(v, str))
        ],
        bands=bands(m.get("by_camera_distance")) if evaluated else [],
        radius=radius if radius is not None and radius > 0 else None,
        views=mesh_views(data, info),
        viewer_note=VIEWER_NOTE,
    )
