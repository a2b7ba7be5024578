"""Ray casting and point-to-surface distances on a triangle mesh: open3d's RaycastingScene (Embree)
behind one small class, so that no other module builds open3d tensors.

open3d works in float32: `Raycaster` takes coordinates relative to an `origin` of the caller's
choice (the centre of the points it will be asked about) to keep their precision.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: Rays or points per open3d query (bounds the float32 copies).
CHUNK = 1 << 20


def raycasting_scene(vertices: np.ndarray, faces: np.ndarray) -> Any:
    """open3d's RaycastingScene over a triangle mesh (coordinates as given, in float32)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.ascontiguousarray(vertices, np.float32)),
        o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)),
    )
    return scene


class Raycaster:
    """A triangle mesh ready for ray and distance queries in world coordinates."""

    def __init__(
        self, vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray | None = None
    ) -> None:
        self.origin = np.zeros(3) if origin is None else np.asarray(origin, np.float64)
        self.scene = raycasting_scene(np.asarray(vertices, np.float64) - self.origin, faces)

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First hit of each ray (N, 3) + (N, 3): the ray parameter t (float64, inf on a miss;
        a distance when the directions are unit vectors) and the face hit (int64, -1 on a
        miss)."""
        import open3d as o3d

        origins = np.broadcast_to(origins, np.shape(directions))
        n = len(directions)
        t = np.empty(n)
        ids = np.empty(n, np.int64)
        invalid = o3d.t.geometry.RaycastingScene.INVALID_ID
        for a in range(0, n, CHUNK):
            sl = slice(a, a + CHUNK)
            rays = np.concatenate([origins[sl] - self.origin, directions[sl]], axis=1)
            hit = self.scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays, np.float32)))
            t[sl] = hit["t_hit"].numpy()
            prim = hit["primitive_ids"].numpy().astype(np.int64)
            ids[sl] = np.where(prim == invalid, -1, prim)
        return t, ids

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Unsigned distance of each point (N, 3) to the nearest point of the mesh."""
        import open3d as o3d

        pts = np.asarray(points, np.float64).reshape(-1, 3)
        out = np.empty(len(pts))
        for a in range(0, len(pts), CHUNK):
            q = np.ascontiguousarray(pts[a : a + CHUNK] - self.origin, np.float32)
            out[a : a + CHUNK] = self.scene.compute_distance(o3d.core.Tensor(q)).numpy()
        return out


def point_to_surface(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unsigned distance of each point (N, 3) to the nearest point of the triangle mesh (inf
    when the mesh has no face)."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    if len(pts) == 0:
        return np.zeros(0)
    if len(np.asarray(faces).reshape(-1, 3)) == 0:
        return np.full(len(pts), np.inf)
    return Raycaster(vertices, faces, origin=pts.mean(0)).distance(pts)
