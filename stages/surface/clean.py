"""Mesh clean-up: the faces no camera sees, small connected components (floaters), pymeshlab's
repairs and Taubin smoothing."""

from __future__ import annotations

from typing import Any

import numpy as np

from endopipe.stages.camera import Camera, camera_rays
from endopipe.stages.surface.mesh import RawMesh
from endopipe.stages.surface.raycast import Raycaster


def cull_unseen(
    mesh: RawMesh,
    c2ws: list[np.ndarray],
    camera: Camera,
    supersample: int = 1,
    dilate: int = 1,
) -> tuple[RawMesh, float]:
    """Keep the faces that some camera sees: the first hit of one of its pixel rays
    (`supersample`^2 rays per pixel), on the face's front (normals face the lumen), then grown
    by `dilate` rings of neighbouring faces (closes the pin holes between rays). Returns the
    mesh and the fraction of faces kept."""
    if mesh.empty:
        return mesh, 1.0
    v, f = mesh.vertices, mesh.faces
    caster = Raycaster(v, f, origin=v.mean(0))
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    k = camera
    if supersample > 1:
        k = k.scaled(k.width * supersample, k.height * supersample)
    seen = np.zeros(len(f), bool)
    for c2w in c2ws:
        o, d = camera_rays(k, np.asarray(c2w, np.float64))
        _, ids = caster.cast(o, d)
        hit = ids >= 0
        ids, d = ids[hit], d[hit]
        front = (n[ids] * d).sum(1) < 0
        seen[ids[front]] = True
    for _ in range(max(dilate, 0)):
        vs = np.zeros(len(v), bool)
        vs[f[seen].ravel()] = True
        seen = vs[f].any(1)
    return RawMesh(v, f[seen], mesh.colours), float(seen.mean())


def component_labels(n_vertices: int, faces: np.ndarray) -> np.ndarray:
    """Connected-component label per face (faces sharing a vertex are connected)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    f = np.asarray(faces, np.int64)
    rows = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    cols = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    g = coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(n_vertices, n_vertices))
    _, labels = connected_components(g, directed=False)
    return labels[f[:, 0]]


def drop_small_components(
    mesh: RawMesh, min_fraction: float, min_diameter: float
) -> tuple[RawMesh, int]:
    """Remove components with fewer faces than min_fraction x the largest's, or a bounding-box
    diagonal under min_diameter. Returns the mesh (vertices unchanged) and components removed."""
    if mesh.empty:
        return mesh, 0
    labels = component_labels(len(mesh.vertices), mesh.faces)
    uniq, inv, counts = np.unique(labels, return_inverse=True, return_counts=True)
    keep_c = counts >= min_fraction * counts.max()
    if min_diameter > 0:
        fv = mesh.vertices[mesh.faces]  # (F, 3, 3)
        lo = np.full((len(uniq), 3), np.inf)
        hi = np.full((len(uniq), 3), -np.inf)
        np.minimum.at(lo, inv, fv.min(1))
        np.maximum.at(hi, inv, fv.max(1))
        keep_c &= np.linalg.norm(hi - lo, axis=1) >= min_diameter
    if not keep_c.any():  # never drop everything: keep the largest
        keep_c[np.argmax(counts)] = True
    faces = mesh.faces[keep_c[inv]]
    return RawMesh(mesh.vertices, faces, mesh.colours), int((~keep_c).sum())


def clean_mesh(
    mesh: RawMesh,
    *,
    min_component_fraction: float,
    min_component_diameter: float,
    smooth_iterations: int,
    taubin_lambda: float = 0.5,
    taubin_mu: float = -0.53,
) -> tuple[RawMesh, dict[str, int]]:
    """pymeshlab clean-up: duplicated vertices / faces, null faces, small components
    (floaters), unreferenced vertices; then Taubin smoothing."""
    import pymeshlab

    if mesh.empty:
        return mesh, {"components_removed": 0}

    def meshset(m: RawMesh) -> pymeshlab.MeshSet:
        kw: dict[str, Any] = {}
        if m.colours is not None:
            c = np.concatenate(
                [m.colours.astype(np.float64) / 255.0, np.ones((len(m.colours), 1))], 1
            )
            kw["v_color_matrix"] = c
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=m.vertices, face_matrix=m.faces, **kw))
        return ms

    def unpack(ms: pymeshlab.MeshSet, with_colour: bool) -> RawMesh:
        cm = ms.current_mesh()
        colours = None
        if with_colour and cm.has_vertex_color():
            colours = np.clip(cm.vertex_color_matrix()[:, :3] * 255.0 + 0.5, 0, 255)
            colours = colours.astype(np.uint8)
        return RawMesh(
            np.asarray(cm.vertex_matrix(), np.float64),
            np.asarray(cm.face_matrix(), np.int64),
            colours,
        )

    has_colour = mesh.colours is not None
    ms = meshset(mesh)
    ms.meshing_remove_duplicate_vertices()
    ms.meshing_remove_duplicate_faces()
    ms.meshing_remove_null_faces()
    ms.meshing_remove_unreferenced_vertices()
    mesh = unpack(ms, has_colour)
    mesh, removed = drop_small_components(mesh, min_component_fraction, min_component_diameter)
    ms = meshset(mesh)
    ms.meshing_remove_unreferenced_vertices()
    if smooth_iterations > 0 and ms.current_mesh().face_number() > 0:
        ms.apply_coord_taubin_smoothing(
            lambda_=taubin_lambda, mu=taubin_mu, stepsmoothnum=int(smooth_iterations)
        )
    return unpack(ms, has_colour), {"components_removed": removed}
