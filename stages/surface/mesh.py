"""The triangle mesh the surface library passes around, and its files (PLY or OBJ via trimesh)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass
class RawMesh:
    """Triangle mesh arrays: vertices (V, 3) float64, faces (F, 3) int64, colours (V, 3) uint8."""

    vertices: np.ndarray
    faces: np.ndarray
    colours: np.ndarray | None = None

    @property
    def empty(self) -> bool:
        return len(self.faces) == 0

    @classmethod
    def empty_mesh(cls) -> RawMesh:
        return cls(np.zeros((0, 3)), np.zeros((0, 3), np.int64))


def write_mesh(path: Path, mesh: RawMesh) -> None:
    """PLY (binary) or OBJ by the suffix, vertex colours when present."""
    import trimesh

    tm = trimesh.Trimesh(
        vertices=mesh.vertices,
        faces=mesh.faces,
        vertex_colors=mesh.colours,
        process=False,
    )
    tm.export(str(path))


def read_mesh(path: Path) -> RawMesh:
    """A mesh file as written by `write_mesh` (or any trimesh reads), vertices untouched. PLY
    goes through open3d: a long recording's ground truth (7M faces) took 1.4 GB more to read
    with trimesh, 0.5 GB with open3d."""
    if Path(path).suffix.lower() == ".ply":
        read = _read_ply(Path(path))
        if read is not None:
            return read
    import trimesh

    tm = trimesh.load(str(path), process=False, force="mesh")
    colours = None
    vc = getattr(tm.visual, "vertex_colors", None)
    if vc is not None and len(vc) == len(tm.vertices):
        colours = np.asarray(vc)[:, :3].astype(np.uint8)
    return RawMesh(np.asarray(tm.vertices, np.float64), np.asarray(tm.faces, np.int64), colours)


def _read_ply(path: Path) -> RawMesh | None:
    """A PLY's triangles through open3d (None: it read no face; trimesh then tries)."""
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(path))
    if not mesh.has_triangles():
        return None
    colours = None
    if mesh.has_vertex_colors():
        colours = np.round(np.asarray(mesh.vertex_colors) * 255.0).astype(np.uint8)
    vertices = np.asarray(mesh.vertices, np.float64).copy()
    faces = np.asarray(mesh.triangles, np.int64)
    return RawMesh(vertices, faces, colours)
