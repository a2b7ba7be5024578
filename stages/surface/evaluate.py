"""Mesh evaluation (docs/formats.md): Chamfer distance, accuracy, completeness and F-score.

Plain functions over arrays (vertices (V, 3), faces (F, 3), OpenCV camera-to-world poses) and
the one `Camera` (its projection and rays, with the lens, from stages/camera); no I/O.

Distances are point-to-surface: points sampled uniformly (by area) on one mesh are measured to
the nearest point of the other mesh's triangles (open3d's RaycastingScene), not to the other
mesh's samples, so two identical meshes score ~0 whatever the sample count. Samples:
`trimesh.sample.sample_surface`, seeded. `nearest_distance` (k-d tree, point-to-point) is there
for point clouds.

What is compared (the crop, `evaluate_mesh`):
- completeness (gt -> est) is measured on the part of the ground-truth surface the cameras
  could see: points sampled on the GT mesh that project inside the image (and the field-of-view
  mask) of at least one registered camera, with z-depth in (0, max_depth], and that are the
  first surface hit along the ray from that camera's centre (occluders: every GT face in or
  near the frustums, which holds every possible occluder).
  Surface hidden behind folds, out of every frustum, or further than max_depth is not asked for.
- accuracy (est -> gt) is measured for estimated points inside at least one camera's frustum up
  to max_depth (no occlusion test: a floater in front of the wall counts), against the whole GT
  mesh (searched only where a nearer face can be, `distance_to_mesh`); estimated surface
  outside every frustum cannot be judged and is left out.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from endopipe.stages.camera import Camera, pixel_directions, project
from endopipe.stages.surface.raycast import Raycaster, point_to_surface

__all__ = [
    "by_camera_distance",
    "chamfer",
    "distance_to_mesh",
    "evaluate_mesh",
    "faces_in_box",
    "faces_near_cameras",
    "frustum_box",
    "fscore",
    "in_any_frustum",
    "in_frustum",
    "nearest_distance",
    "point_to_surface",
    "sample_surface",
    "surface_metrics",
    "transform_points",
    "visible_from_cameras",
]


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """`n` points uniformly distributed (by area) on a triangle mesh; (n, 3) float64 (trimesh's
    sampler, seeded); none when the mesh has no area."""
    import trimesh

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    if len(f) == 0 or n <= 0:
        return np.zeros((0, 3))
    mesh = trimesh.Trimesh(vertices=v, faces=f, process=False, validate=False)
    if not mesh.area > 0:
        return np.zeros((0, 3))
    points, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return np.asarray(points, np.float64)


def nearest_distance(points: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Distance of each point (N, 3) to its nearest neighbour in `reference` (M, 3)."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    ref = np.asarray(reference, np.float64).reshape(-1, 3)
    if len(ref) == 0:
        return np.full(len(pts), np.inf)
    return cKDTree(ref).query(pts, k=1, workers=-1)[0]


def in_frustum(
    points: np.ndarray,
    c2w: np.ndarray,
    camera: Camera,
    max_depth: float,
    mask: np.ndarray | None = None,
    margin_px: float = 0.0,
) -> np.ndarray:
    """Whether each point projects (through the camera's lens) inside the image (pixel centres
    0..W-1, 0..H-1, grown by `margin_px`) and inside `mask` (HxW, nonzero = seen) with z-depth
    in (0, max_depth]."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    w2c = np.linalg.inv(np.asarray(c2w, np.float64))
    z = pts @ w2c[2, :3] + w2c[2, 3]
    ok = (z > 0) & (z <= max_depth)
    idx = np.nonzero(ok)[0]
    if len(idx) == 0:
        return ok
    uv, _ = project(camera, pts[idx], c2w)
    u, v = uv[:, 0], uv[:, 1]
    width, height = camera.width, camera.height
    m = margin_px + 0.5
    inside = (u >= -m) & (u <= width - 1 + m) & (v >= -m) & (v <= height - 1 + m)
    if mask is not None:  # a lens gives no pixel (NaN) past where it bends back: outside
        ui = np.clip(np.round(np.where(inside, u, 0)).astype(np.int64), 0, width - 1)
        vi = np.clip(np.round(np.where(inside, v, 0)).astype(np.int64), 0, height - 1)
        inside &= np.asarray(mask)[vi, ui] > 0
    ok[idx] = inside
    return ok


def in_any_frustum(
    points: np.ndarray,
    c2ws: list[np.ndarray],
    camera: Camera,
    max_depth: float,
    mask: np.ndarray | None = None,
    margin_px: float = 0.0,
) -> np.ndarray:
    """Whether each point lies in the frustum (up to max_depth) of at least one camera."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    seen = np.zeros(len(pts), bool)
    for c2w in c2ws:
        todo = np.nonzero(~seen)[0]
        if len(todo) == 0:
            break
        seen[todo] = in_frustum(pts[todo], c2w, camera, max_depth, mask, margin_px)
    return seen


def visible_from_cameras(
    points: np.ndarray,
    c2ws: list[np.ndarray],
    camera: Camera,
    max_depth: float,
    vertices: np.ndarray,
    faces: np.ndarray,
    mask: np.ndarray | None = None,
    tol: float = 0.005,
) -> np.ndarray:
    """Whether each surface point (on the mesh vertices/faces) is seen by at least one camera:
    in its frustum up to max_depth (and in `mask`), and the first hit of the ray from the camera
    centre through it (a hit closer than (1 - tol) x the point's distance occludes it)."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    seen = np.zeros(len(pts), bool)
    if len(pts) == 0:
        return seen
    caster = Raycaster(vertices, faces, origin=pts.mean(0))
    for c2w in c2ws:
        todo = np.nonzero(~seen)[0]
        if len(todo) == 0:
            break
        cand = todo[in_frustum(pts[todo], c2w, camera, max_depth, mask)]
        if len(cand) == 0:
            continue
        origin = np.asarray(c2w, np.float64)[:3, 3]
        vec = pts[cand] - origin
        dist = np.linalg.norm(vec, axis=1)
        t, _ = caster.cast(origin, vec / np.maximum(dist, 1e-12)[:, None])
        seen[cand] |= t >= dist * (1.0 - tol)
    return seen


#: The widest a frustum's box reaches off the axis (a pinhole up to 150 degrees across is
#: boxed whole).
FRUSTUM_MAX_DEG = 75.0


def frustum_box(
    c2ws: list[np.ndarray], camera: Camera, max_depth: float
) -> tuple[np.ndarray, np.ndarray]:
    """World bounding box (lo, hi) of the cameras' frustums: apexes and far-plane corners (the
    rays through the image's outer corners, the lens undone). A wide fisheye's corner rays
    run near 90 degrees off the axis, where the far plane lies tens of depths out to the side:
    they are taken at most FRUSTUM_MAX_DEG off it (what lies further out is not boxed)."""
    w, h = camera.width, camera.height
    cu = np.array([-0.5, w - 0.5, -0.5, w - 0.5])
    cv = np.array([-0.5, -0.5, h - 0.5, h - 0.5])
    rays = np.array(pixel_directions(camera, cu, cv), np.float64)  # z = 1
    side = np.linalg.norm(rays[:, :2], axis=1, keepdims=True)
    rays[:, :2] *= np.minimum(1.0, np.tan(np.radians(FRUSTUM_MAX_DEG)) / np.maximum(side, 1e-12))
    pts = []
    for c2w in c2ws:
        c2w = np.asarray(c2w, np.float64)
        pts.append(c2w[:3, 3][None])
        pts.append((rays * max_depth) @ c2w[:3, :3].T + c2w[:3, 3])
    allp = np.concatenate(pts)
    return allp.min(0), allp.max(0)


def faces_near_cameras(
    vertices: np.ndarray,
    faces: np.ndarray,
    c2ws: list[np.ndarray],
    camera: Camera,
    max_depth: float,
    slack: float = 0.05,
) -> np.ndarray:
    """Faces with a vertex in some camera's frustum, grown by `slack` (fraction of the image
    size and of max_depth): a cheap superset of the visible surface (and of its occluders)."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    lo, hi = frustum_box(c2ws, camera, max_depth * (1.0 + slack))
    pad = slack * max_depth
    cand = np.nonzero(((v >= lo - pad) & (v <= hi + pad)).all(1))[0]
    near_v = np.zeros(len(v), bool)
    margin = slack * max(camera.width, camera.height)
    near_v[cand] = in_any_frustum(v[cand], c2ws, camera, max_depth * (1.0 + slack), None, margin)
    return f[near_v[f].any(1)]


def fscore(d_acc: np.ndarray, d_comp: np.ndarray, threshold: float) -> tuple[float, float, float]:
    """(precision, recall, F-score) at `threshold` from est->gt and gt->est distances."""
    p = float(np.mean(d_acc < threshold)) if len(d_acc) else 0.0
    r = float(np.mean(d_comp < threshold)) if len(d_comp) else 0.0
    f = 2 * p * r / (p + r) if p + r > 0 else 0.0
    return p, r, f


def surface_metrics(d_acc: np.ndarray, d_comp: np.ndarray, threshold: float) -> dict[str, float]:
    """Accuracy (mean est->gt), completeness (mean gt->est), Chamfer (their mean), medians,
    precision / recall / F-score at `threshold`. inf where a side has no points."""
    acc = float(np.mean(d_acc)) if len(d_acc) else float("inf")
    comp = float(np.mean(d_comp)) if len(d_comp) else float("inf")
    p, r, f = fscore(d_acc, d_comp, threshold)
    return {
        "chamfer": 0.5 * (acc + comp),
        "accuracy": acc,
        "completeness": comp,
        "accuracy_median": float(np.median(d_acc)) if len(d_acc) else float("inf"),
        "completeness_median": float(np.median(d_comp)) if len(d_comp) else float("inf"),
        "precision": p,
        "recall": r,
        "fscore": f,
        "threshold": float(threshold),
    }


def by_camera_distance(
    est_points: np.ndarray,
    d_acc: np.ndarray,
    gt_points: np.ndarray,
    d_comp: np.ndarray,
    centres: np.ndarray,
    edges: list[float],
) -> list[dict[str, float | None]]:
    """Accuracy and completeness of the points whose nearest camera centre lies in each band
    [edges[k], edges[k+1]): depth error grows with distance, so one mean hides where the mesh
    can be trusted (the surface the scope passed close to) and where it cannot."""
    near_est = nearest_distance(est_points, centres)
    near_gt = nearest_distance(gt_points, centres)
    rows: list[dict[str, float | None]] = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        a = d_acc[(near_est >= lo) & (near_est < hi)]
        c = d_comp[(near_gt >= lo) & (near_gt < hi)]
        acc = float(a.mean()) if len(a) else None
        comp = float(c.mean()) if len(c) else None
        rows.append(
            {
                "from": float(lo),
                "to": float(hi),
                "accuracy": acc,
                "completeness": comp,
                "chamfer": 0.5 * (acc + comp) if acc is not None and comp is not None else None,
                "est_share": float(len(a) / max(len(d_acc), 1)),
                "gt_share": float(len(c) / max(len(d_comp), 1)),
            }
        )
    return rows


def chamfer(
    est_vertices: np.ndarray,
    est_faces: np.ndarray,
    gt_vertices: np.ndarray,
    gt_faces: np.ndarray,
    threshold: float,
    n_samples: int = 100_000,
    seed: int = 0,
) -> dict[str, float]:
    """Metrics of two whole meshes (no crop): `n_samples` points on each, point-to-surface."""
    est_pts = sample_surface(est_vertices, est_faces, n_samples, seed)
    gt_pts = sample_surface(gt_vertices, gt_faces, n_samples, seed + 1)
    d_acc = point_to_surface(est_pts, gt_vertices, gt_faces)
    d_comp = point_to_surface(gt_pts, est_vertices, est_faces)
    return surface_metrics(d_acc, d_comp, threshold)


def evaluate_mesh(
    est_vertices: np.ndarray,
    est_faces: np.ndarray,
    gt_vertices: np.ndarray,
    gt_faces: np.ndarray,
    c2ws: list[np.ndarray],
    camera: Camera,
    max_depth: float,
    threshold: float,
    *,
    mask: np.ndarray | None = None,
    n_samples: int = 200_000,
    occlusion: bool = True,
    seed: int = 0,
    distance_bands: list[float] | None = None,
    off_seen: float | None = None,
) -> dict[str, Any]:
    """Metrics of an estimated mesh against the part of the GT mesh the cameras could see.

    All inputs share the GT's world frame and units (align first). `c2ws`, `camera`, `mask`:
    the registered cameras; `max_depth`: the depth up to which surface counts
    as seen (the reconstruction's depth truncation). See the module docstring for the crop.
    Adds to `surface_metrics`: gt_area_seen (area of the GT surface in the crop), the share of
    GT samples kept, the number of points on each side, and with `distance_bands` (edges of
    the distance to the nearest camera centre) the metrics per band (`by_camera_distance`).
    With `off_seen` (a distance), `off_seen_pct`: the % of the estimated surface farther than
    it from any GT surface a camera saw (made up, or misplaced, rather than reconstructed).
    """
    gt_v = np.asarray(gt_vertices, np.float64)
    gt_f = np.asarray(gt_faces, np.int64).reshape(-1, 3)
    near = faces_near_cameras(gt_v, gt_f, c2ws, camera, max_depth)
    gt_pts = sample_surface(gt_v, near, n_samples, seed + 1)
    if occlusion:  # occluders lie in the frustums too: the near faces suffice
        keep = visible_from_cameras(gt_pts, c2ws, camera, max_depth, gt_v, near, mask)
    else:
        keep = in_any_frustum(gt_pts, c2ws, camera, max_depth, mask)
    gt_pts = gt_pts[keep]
    a, b, c = gt_v[near[:, 0]], gt_v[near[:, 1]], gt_v[near[:, 2]]
    near_area = float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())

    est_pts = sample_surface(est_vertices, est_faces, n_samples, seed)
    est_pts = est_pts[in_any_frustum(est_pts, c2ws, camera, max_depth, mask)]

    d_acc = distance_to_mesh(est_pts, gt_v, gt_f, near)
    d_comp = point_to_surface(gt_pts, est_vertices, est_faces)
    out = surface_metrics(d_acc, d_comp, threshold)
    frac = float(keep.mean()) if len(keep) else 0.0
    out.update(
        gt_area_seen=near_area * frac,
        gt_points=int(len(gt_pts)),
        est_points=int(len(est_pts)),
    )
    if off_seen is not None and len(est_pts) and len(gt_pts):
        off = nearest_distance(est_pts, gt_pts) > off_seen
        out.update(off_seen_pct=100.0 * float(off.mean()), off_seen_threshold=float(off_seen))
    if distance_bands:
        centres = np.array([np.asarray(c, np.float64)[:3, 3] for c in c2ws])
        out["by_camera_distance"] = by_camera_distance(
            est_pts, d_acc, gt_pts, d_comp, centres, distance_bands
        )
    return out


def distance_to_mesh(
    points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, guess: np.ndarray
) -> np.ndarray:
    """`point_to_surface` against the whole mesh, without building a search structure over all
    of it: the distances to the faces `guess` (a subset) bound the true ones from above, so only
    faces that reach into the points' box grown by those distances can be nearer. On a long
    recording's ground truth (millions of faces) a window's evaluation stays the size of what
    its cameras saw."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    bound = point_to_surface(pts, vertices, guess)
    if len(pts) == 0 or not np.all(np.isfinite(bound)):
        return point_to_surface(pts, vertices, faces)
    lo = (pts - bound[:, None]).min(0)
    hi = (pts + bound[:, None]).max(0)
    reach = faces_in_box(vertices, faces, lo, hi)
    if len(reach) == len(np.asarray(faces).reshape(-1, 3)):
        return point_to_surface(pts, vertices, faces)
    return np.minimum(bound, point_to_surface(pts, vertices, reach))


def faces_in_box(
    vertices: np.ndarray, faces: np.ndarray, lo: np.ndarray, hi: np.ndarray, chunk: int = 1 << 20
) -> np.ndarray:
    """Faces whose bounding box overlaps the box [lo, hi] (a superset of those meeting it),
    in chunks of faces so a large mesh needs no (F, 3, 3) array."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    keep = np.zeros(len(f), bool)
    for a in range(0, len(f), chunk):
        tri = v[f[a : a + chunk]]  # (n, 3 corners, 3 axes)
        keep[a : a + chunk] = ((tri.max(1) >= lo) & (tri.min(1) <= hi)).all(1)
    return f[keep]


def transform_points(points: np.ndarray, s: float, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """x -> s R x + t for (N, 3) points (a similarity, e.g. from Umeyama)."""
    return s * np.asarray(points, np.float64) @ np.asarray(R).T + np.asarray(t)
