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
    """A mesh file as written by `write_mesh` (or any trimesh reads), vertices untouched."""
    import trimesh

    tm = trimesh.load(str(path), process=False, force="mesh")
    colours = None
    vc = getattr(tm.visual, "vertex_colors", None)
    if vc is not None and len(vc) == len(tm.vertices):
        colours = np.asarray(vc)[:, :3].astype(np.uint8)
    return RawMesh(np.asarray(tm.vertices, np.float64), np.asarray(tm.faces, np.int64), colours)
