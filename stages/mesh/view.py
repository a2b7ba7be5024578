"""06_mesh (docs/formats.md): mesh.ply (optionally mesh.obj) and metrics.json, written and read here
only: the mesh stage saves through `save_mesh` and `MeshMetrics.write` (metrics_file.py),
everyone else reads through `MeshView`."""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

from endopipe.pipeline.stage import read_summary
from endopipe.stages.mesh.metrics_file import MeshMetrics
from endopipe.stages.mesh.summary import MeshSummary
from endopipe.stages.surface.mesh import RawMesh, read_mesh, write_mesh

MESH_FILE = "mesh.ply"
OBJ_FILE = "mesh.obj"


def save_mesh(folder: Path, mesh: RawMesh, obj: bool = False) -> None:
    """mesh.ply (and mesh.obj with `obj`), world frame and units of cameras.json."""
    write_mesh(Path(folder) / MESH_FILE, mesh)
    if obj:
        write_mesh(Path(folder) / OBJ_FILE, mesh)


class MeshView:
    """Typed access to 06_mesh: the mesh file(s) and the evaluation."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.mesh_path = self.folder / MESH_FILE
        obj = self.folder / OBJ_FILE
        self.obj_path: Path | None = obj if obj.is_file() else None
        #: metrics.json (None when absent); read at once, so a malformed one fails here
        self.metrics: MeshMetrics | None = MeshMetrics.read(self.folder)

    @cached_property
    def summary(self) -> MeshSummary:
        """The stage's summary in its manifest, as the model the stage wrote (SummaryMismatch
        when the folder was written with other fields)."""
        return read_summary(self.folder, MeshSummary)

    @property
    def evaluated(self) -> bool:
        return self.metrics is not None and self.metrics.evaluated

    def load(self) -> RawMesh:
        return read_mesh(self.mesh_path)
