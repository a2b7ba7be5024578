"""06_mesh (docs/formats.md): mesh.ply (optionally mesh.obj) and metrics.json, written and read here
only: the mesh stage saves through `save_mesh` / `save_metrics`, everyone else reads through
`MeshView`."""

from __future__ import annotations

import json
from functools import cached_property
from pathlib import Path
from typing import Any, cast

from pydantic import TypeAdapter
from typing_extensions import TypedDict  # pydantic validates only this one on Python < 3.12

from endopipe.pipeline.stage import read_summary, write_json
from endopipe.stages.mesh.summary import MeshSummary
from endopipe.stages.surface.mesh import RawMesh, read_mesh, write_mesh

MESH_FILE = "mesh.ply"
OBJ_FILE = "mesh.obj"
METRICS_FILE = "metrics.json"

#: One row of metrics.json's by_camera_distance ("from" is a Python keyword: functional form).
DistanceBand = TypedDict(
    "DistanceBand",
    {
        "from": float,
        "to": float | None,  # the open last band is written as null
        "accuracy": float | None,
        "completeness": float | None,
        "chamfer": float | None,
        "chamfer_pct_radius": float | None,
        "est_share": float,
        "gt_share": float,
    },
    total=False,
)


class MeshMetrics(TypedDict, total=False):
    """metrics.json as the mesh stage writes it: flat keys, JSON null for inf / nan. The
    evaluation keys are there when `evaluated`, else `reason` says why not."""

    evaluated: bool
    reason: str
    gt_kind: str
    # against the ground-truth mesh (stages.surface.evaluate), in GT units
    chamfer: float | None
    chamfer_pct_radius: float | None
    accuracy: float | None
    completeness: float | None
    accuracy_median: float | None
    completeness_median: float | None
    precision: float
    recall: float
    fscore: float
    threshold: float
    gt_area_seen: float
    gt_points: int
    est_points: int
    by_camera_distance: list[DistanceBand]
    aligned: str  # "gt_frame" | "sim3"
    sim3_scale: float
    mean_radius: float | None
    crop_max_depth: float
    crop: str
    eval_s: float
    # how the surface was made
    method: str
    vertices: int  # in mesh.ply, after clean-up
    faces: int
    raw_vertices: int  # as built, before clean-up
    raw_faces: int
    voxel_size: float
    sdf_trunc: float
    depth_trunc: float
    frames_used: int
    level: float
    band_nodes: int
    faces_extracted: int
    seen_fraction: float
    components_removed: int


_METRICS = TypeAdapter(MeshMetrics)


def save_mesh(folder: Path, mesh: RawMesh, obj: bool = False) -> None:
    """mesh.ply (and mesh.obj with `obj`), world frame and units of cameras.json."""
    write_mesh(Path(folder) / MESH_FILE, mesh)
    if obj:
        write_mesh(Path(folder) / OBJ_FILE, mesh)


def save_metrics(folder: Path, metrics: dict[str, Any]) -> None:
    """metrics.json, checked against `MeshMetrics` first (key order kept as given)."""
    _METRICS.validate_python(metrics)
    write_json(Path(folder) / METRICS_FILE, metrics)


class MeshView:
    """Typed access to 06_mesh: the mesh file(s) and the evaluation."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.mesh_path = self.folder / MESH_FILE
        obj = self.folder / OBJ_FILE
        self.obj_path: Path | None = obj if obj.is_file() else None
        self.metrics: MeshMetrics = self._read_metrics(self.folder / METRICS_FILE)

    @cached_property
    def summary(self) -> MeshSummary:
        """The stage's summary in its manifest, as the model the stage wrote (SummaryMismatch
        when the folder was written with other fields)."""
        return read_summary(self.folder, MeshSummary)

    @staticmethod
    def _read_metrics(path: Path) -> MeshMetrics:
        """The file as written (key order kept for the report), validated; {} when absent."""
        if not path.is_file():
            return {}
        raw = path.read_text()
        _METRICS.validate_json(raw)  # raises a ValueError on a malformed file
        return cast(MeshMetrics, json.loads(raw))

    @property
    def evaluated(self) -> bool:
        return bool(self.metrics.get("evaluated"))

    def load(self) -> RawMesh:
        return read_mesh(self.mesh_path)
