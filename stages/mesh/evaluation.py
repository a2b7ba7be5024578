"""The mesh stage's evaluation against the case's ground truth (docs/formats.md): alignment of the
reconstruction to the ground truth's frame, the crop's cameras and depth, then
stages.surface.evaluate. Ground truth comes through the one door (`open_ground_truth`,
`poses_by_frame`)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import apply_sim3, umeyama
from endopipe.stages.io.datasets import open_ground_truth
from endopipe.stages.io.ground_truth import GroundTruthSource
from endopipe.stages.mesh.config import MeshConfig
from endopipe.stages.surface.evaluate import evaluate_mesh, transform_points
from endopipe.stages.surface.mesh import RawMesh, read_mesh

if TYPE_CHECKING:
    from endopipe.stages.poses.view import PosesView

#: Bands of the distance to the nearest camera centre, in lumen radii, for metrics.json's
#: by_camera_distance (the last band is open).
DISTANCE_BANDS_RADII = (0.0, 1.0, 1.5, 2.0, 3.0, float("inf"))
#: mesh farther than this (in radii) from every GT surface a camera saw counts as made up
OFF_SEEN_RADII = 0.1


def case_ground_truth(gt_dir: Path | str | None) -> GroundTruthSource | None:
    """The case's ground truth, or None when it has none or it cannot be read."""
    if not gt_dir:
        return None
    try:
        return open_ground_truth(gt_dir)
    except (InputError, ValueError, OSError):
        return None


def ground_truth_mesh(gt: GroundTruthSource | None) -> Path | None:
    """The ground truth's surface file, when its format has one."""
    mesh_path = getattr(gt, "mesh_path", None)
    return mesh_path() if callable(mesh_path) else None


def evaluate_against_gt(
    mesh: RawMesh,
    poses: PosesView,
    gt_mesh_path: Path,
    gt_poses: dict[int, np.ndarray] | None,
    depth_trunc: float,
    cfg: MeshConfig,
    *,
    gt_radius: float | None = None,
    est_radius: float | None = None,
    fov_mask: np.ndarray | None = None,
) -> dict[str, Any]:
    """metrics.json of a mesh in cameras.json's frame against a GT mesh.

    `gt_poses`: GT c2w per endopipe frame index (None: none known). Poses aligned to the truth:
    already in the GT frame; metric in their own frame (a stereo rig's scale): the rigid motion
    (Umeyama without scale, or one still camera's pose) onto the truth; else sim3 (Umeyama) of
    the registered centres onto the GT centres. The crop
    cameras are the registered frames at their GT poses (the aligned estimates when no GT pose),
    the depth limit `depth_trunc` x the sim3 scale. Radius for chamfer_pct_radius: `gt_radius`
    (gt/centerline.json), else `est_radius` (cameras.json units) x scale.
    """
    common = sorted(set(poses.registered) & set(gt_poses or {}))
    src = np.array([poses.c2w[i][:3, 3] for i in common]).reshape(-1, 3)
    path = len(common) >= 3 and float(np.ptp(src, axis=0).max()) > 0.0
    if poses.in_gt_frame:
        s, R, t, aligned = 1.0, np.eye(3), np.zeros(3), "gt_frame"
    elif poses.metric and common and not path:
        # millimetres in the camera's own frame, one place: the truth's pose of that frame
        # maps it (a rigid motion: the scale is what is scored)
        i = common[0]
        move = np.asarray(gt_poses[i], np.float64) @ np.linalg.inv(poses.c2w[i])  # type: ignore[index]
        s, R, t, aligned = 1.0, move[:3, :3], move[:3, 3], "rigid"
    elif path:
        dst = np.array([gt_poses[i][:3, 3] for i in common])  # type: ignore[index]
        # metric poses (a stereo rig's scale) keep their scale: only a rigid motion is fitted
        s, R, t = umeyama(src, dst, with_scale=not poses.metric)
        aligned = "rigid" if poses.metric else "sim3"
    else:
        return {"evaluated": False, "reason": "cameras not metric and fewer than 3 GT poses"}

    gt = read_mesh(gt_mesh_path)
    verts = transform_points(mesh.vertices, s, R, t)
    cams = [
        np.asarray(gt_poses[i], np.float64)
        if gt_poses is not None and i in gt_poses
        else apply_sim3(s, R, t, poses.c2w[i])
        for i in poses.registered
    ]
    k = poses.intrinsics
    radius = (
        gt_radius if gt_radius is not None else (est_radius * s if est_radius is not None else None)
    )
    threshold = cfg.fscore_threshold
    if cfg.fscore_threshold_pct_radius is not None and radius is not None:
        threshold = cfg.fscore_threshold_pct_radius / 100.0 * radius
    mask = fov_mask if fov_mask is not None and fov_mask.shape == (k.height, k.width) else None
    t0 = time.perf_counter()
    m = evaluate_mesh(
        verts,
        mesh.faces,
        gt.vertices,
        gt.faces,
        cams,
        k,
        depth_trunc * s,
        threshold,
        mask=mask,
        n_samples=cfg.eval_samples,
        occlusion=cfg.eval_occlusion,
        distance_bands=[b * radius for b in DISTANCE_BANDS_RADII] if radius else None,
        off_seen=OFF_SEEN_RADII * radius if radius else None,
    )
    for band in m.get("by_camera_distance", []):
        band["chamfer_pct_radius"] = (
            100.0 * band["chamfer"] / radius if band["chamfer"] is not None else None
        )
    out: dict[str, Any] = {"evaluated": True}
    out["chamfer"] = m["chamfer"]
    out["chamfer_pct_radius"] = 100.0 * m["chamfer"] / radius if radius else None
    out.update({k2: v for k2, v in m.items() if k2 != "chamfer"})
    out.update(
        aligned=aligned,
        sim3_scale=float(s),
        mean_radius=radius,
        crop_max_depth=float(depth_trunc * s),
        crop="gt surface visible (first hit) from registered cameras within crop_max_depth"
        if cfg.eval_occlusion
        else "gt surface in registered cameras' frustums within crop_max_depth",
        eval_s=round(time.perf_counter() - t0, 2),
    )
    return out
