"""ply: `mesh.ply` (06_mesh, world frame), `points.ply` and `cameras.ply`, written by trimesh.

`points.ply` is a coloured point cloud fused from 05_depth: every `point_stride`-th pixel inside
the usable mask, back-projected through the camera's lens at the pose its depth was rendered at
(so the points lie on the mesh), voxel-thinned to at most `max_points`. `cameras.ply`: the camera
centres at those poses, in frame order.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np

from endopipe.export.case import CaseExport, ExportResult
from endopipe.pipeline.errors import EndopipeError
from endopipe.stages.camera import backproject
from endopipe.stages.io.colmap_model import write_ply

CAMERA_COLOUR = (255, 64, 32)


def fuse_depth(
    case: CaseExport, stride: int = 4, max_points: int = 2_000_000
) -> tuple[np.ndarray, np.ndarray]:
    """World points (N, 3) and colours (N, 3 uint8) back-projected from the depth maps."""
    xyz, rgb = [], []
    for f in case.frames:
        if not f.has_depth:
            continue
        d = case.depth(f).astype(np.float64)
        h, w = d.shape
        valid = (d > 0) & np.isfinite(d)
        if f.mask is not None:
            m = cv2.imread(str(f.mask), cv2.IMREAD_GRAYSCALE)
            if m is not None:
                valid &= cv2.resize(m, (w, h), interpolation=cv2.INTER_NEAREST) > 127
        sub = np.zeros_like(valid)
        sub[::stride, ::stride] = True
        valid &= sub
        pts = backproject(case.intrinsics, d, f.c2w)[valid]  # scaled to the map when it differs
        if f.image is not None:
            img = cv2.imread(str(f.image), cv2.IMREAD_COLOR)
            img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
            col = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)[valid]
        else:
            col = np.full((len(pts), 3), 200, np.uint8)
        xyz.append(pts)
        rgb.append(col)
    if not xyz:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    points, colours = np.concatenate(xyz), np.concatenate(rgb)
    if len(points) > max_points:
        points, colours = voxel_thin(points, colours, max_points)
    return points, colours


def voxel_thin(
    points: np.ndarray, colours: np.ndarray, max_points: int
) -> tuple[np.ndarray, np.ndarray]:
    """open3d's voxel down-sampling (one point per voxel: the mean of its points and colours),
    the voxel grown until at most `max_points` remain."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    cloud.colors = o3d.utility.Vector3dVector(np.asarray(colours, np.float64) / 255.0)
    extent = float(np.ptp(points, axis=0).max()) or 1.0
    size = extent / max(np.cbrt(max_points), 1.0) / 4
    for _ in range(40):
        thin = cloud.voxel_down_sample(size)
        if len(thin.points) <= max_points:
            rgb = np.round(np.asarray(thin.colors) * 255.0).clip(0, 255).astype(np.uint8)
            return np.asarray(thin.points), rgb
        size *= 1.25
    return points[:max_points], colours[:max_points]


def write_ply_export(
    case: CaseExport, out: Path, *, stride: int = 4, max_points: int = 2_000_000
) -> ExportResult:
    from endopipe.stages.mesh.view import MeshView

    notes, files = [], []
    mesh = case.view("mesh", MeshView)
    if mesh is not None and mesh.mesh_path.is_file():
        shutil.copy2(mesh.mesh_path, out / "mesh.ply")
        files.append("mesh.ply")
    else:
        notes.append("no 06_mesh/mesh.ply")
    if case.has_depth():
        xyz, rgb = fuse_depth(case, stride, max_points)
        write_ply(out / "points.ply", xyz, rgb)
        files.append("points.ply")
        notes.append(f"points.ply: {len(xyz):,} points fused from the depth maps (stride {stride})")
    else:
        notes.append("no 05_depth: no fused point cloud")
    if not files:
        raise EndopipeError(
            f"{case.case_dir.name}: nothing to export as PLY (no 06_mesh/mesh.ply, no 05_depth); "
            "run the pipeline through the depth or mesh stage first"
        )
    centres = np.array([f.c2w[:3, 3] for f in case.frames])
    write_ply(out / "cameras.ply", centres, np.tile(CAMERA_COLOUR, (len(centres), 1)))
    files.append("cameras.ply")
    if case.refined:
        notes.append("poses refined by the NeRF: those the depth maps were rendered at")
    return ExportResult("ply", out, len(case.frames), files, notes)
