"""06_mesh (docs/formats.md): mesh.ply (optionally mesh.obj), times/ (a scene that moves) and
metrics.json, written and read here
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
#: a scene that moves: one surface per chosen frame, times/mesh_<frame>.ply
TIMES_DIR = "times"


def save_mesh(folder: Path, mesh: RawMesh, obj: bool = False) -> None:
    """mesh.ply (and mesh.obj with `obj`), world frame and units of cameras.json."""
    write_mesh(Path(folder) / MESH_FILE, mesh)
    if obj:
        write_mesh(Path(folder) / OBJ_FILE, mesh)


def save_time_mesh(folder: Path, frame: int, mesh: RawMesh) -> None:
    """times/mesh_<frame>.ply: the surface at one frame's time, frame and units as mesh.ply."""
    (Path(folder) / TIMES_DIR).mkdir(exist_ok=True)
    write_mesh(Path(folder) / TIMES_DIR / f"mesh_{frame:06d}.ply", mesh)


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

    @property
    def time_meshes(self) -> dict[int, Path]:
        """A scene that moves: the surface file of each frame that has one, by frame index."""
        folder = self.folder / TIMES_DIR
        if not folder.is_dir():
            return {}
        return {int(p.stem.split("_")[-1]): p for p in sorted(folder.glob("mesh_*.ply"))}

    def load_time(self, frame: int) -> RawMesh:
        return read_mesh(self.time_meshes[frame])
