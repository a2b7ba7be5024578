"""One mesh over a whole recording: every keyframe's depth map, from the window that posed it
in the joined trajectory, fused into one TSDF (open3d's voxel-block grid grows with the surface,
not with a box around it) in the first segment's frame and units; evaluated against the
ground-truth mesh, when there is one, as the mesh stage evaluates a case's.

Frames stream into the fusion one at a time: memory grows with the surface, not the frames.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from endopipe.pipeline.runner import Pipeline
from endopipe.pipeline.stage import StageConfig
from endopipe.recording.join import Joined
from endopipe.recording.summary import RecordingSummary
from endopipe.stages.camera import Camera
from endopipe.stages.mesh.config import MeshConfig
from endopipe.stages.mesh.inputs import auto_depth_trunc, valid_depth
from endopipe.stages.surface.mesh import RawMesh
from endopipe.stages.surface.tsdf import DepthFrame, tsdf_fuse


@dataclass
class JoinedCameras:
    """The joined trajectory as the mesh evaluation reads a case's cameras (segment 0)."""

    c2w: dict[int, np.ndarray]  # by source_index
    intrinsics: Camera
    metric: bool = False
    #: The joined path lies in its first segment's frame, never the truth's: the evaluation fits
    #: it onto the truth's cameras (sim3, or rigid when metric).
    in_gt_frame: bool = False

    @property
    def registered(self) -> list[int]:
        return sorted(self.c2w)


@dataclass
class WindowFields:
    """What one window contributes: its depth maps and the poses they were rendered at, by
    source_index, and how its frame maps into the segment's."""

    depth: Any  # DepthView
    index: dict[int, int]  # source_index -> the window's frame index
    c2w: dict[int, np.ndarray]  # the window's frame index -> c2w the depth was rendered at
    camera: Camera
    scale: float
    radius: float  # the window's lumen radius, in its own units


def window_fields(pipe: Pipeline, window_dir: Path, scale: float) -> WindowFields | None:
    """A window's depth and poses through its stages' views (None: it has no depth maps)."""
    try:
        depth = pipe.view(window_dir, "depth")
        poses = pipe.view(window_dir, "poses")
        ingest = pipe.view(window_dir, "ingest")
        nerf = pipe.view(window_dir, "nerf")
        radius = float(pipe.view(window_dir, "centerline").prior().typical_radius)
    except (OSError, ValueError):
        return None
    index = {f.source_index: f.index for f in ingest.frames}
    return WindowFields(depth, index, nerf.c2w(poses), poses.intrinsics, scale, radius)


def fuse_recording(
    pipe: Pipeline, windows_dir: Path, joined: Joined, cfg: MeshConfig
) -> tuple[RawMesh, dict[str, float], JoinedCameras] | None:
    """The fused surface of segment 0 (None when no window has depth maps), its settings
    (voxel_size, depth_trunc, frames_used) and the cameras it is in."""
    fields: dict[str, WindowFields] = {}
    for name, sim in joined.windows.items():
        found = window_fields(pipe, windows_dir / name, sim.s)
        if found is not None:
            fields[name] = found
    frames = [f for f in joined.frames if f.segment == 0 and f.window in fields]
    frames = [
        f
        for f in frames
        if fields[f.window].depth.has_depth(fields[f.window].index[f.source_index])
    ]
    if not fields or not frames:
        return None
    radius = float(np.median([w.radius * w.scale for w in fields.values()]))
    voxel = cfg.voxel_size or radius / cfg.voxels_per_radius

    def maps() -> Iterator[tuple[Any, np.ndarray]]:
        for f in frames:
            w = fields[f.window]
            i = w.index[f.source_index]
            scale = np.float32(joined.depth_scale(f.window, f.source_index))
            yield f, valid_depth(w.depth, i, cfg.min_opacity) * scale

    trunc = cfg.depth_trunc or auto_depth_trunc((d for _, d in maps()), cfg.depth_trunc_percentile)

    def pose(f: Any) -> np.ndarray:  # where the window rendered it, in the segment's frame
        w = fields[f.window]
        return joined.place(f.window, f.source_index, w.c2w[w.index[f.source_index]])

    views = (DepthFrame(d, pose(f), None, fields[f.window].camera) for f, d in maps())
    first = fields[frames[0].window].camera
    mesh, used = tsdf_fuse(
        views, first, voxel, cfg.sdf_trunc_voxels * voxel, trunc, False, cfg.min_observations
    )
    cams = JoinedCameras({f.source_index: pose(f) for f in frames}, first)
    info = {"voxel_size": voxel, "depth_trunc": trunc, "frames_used": used, "radius": radius}
    return mesh, info, cams


def one_mesh(
    pipe: Pipeline,
    windows_dir: Path,
    joined: Joined,
    configs: dict[str, StageConfig],
    ingest,
    truth: list[np.ndarray] | None,
    summary: RecordingSummary,
):
    """The windows' depth fused into one cleaned mesh; its scores into `summary`."""
    from endopipe.stages.mesh.evaluation import (
        case_ground_truth,
        evaluate_against_gt,
        ground_truth_mesh,
    )
    from endopipe.stages.surface.clean import clean_mesh

    cfg = configs["mesh"]
    fused = fuse_recording(pipe, windows_dir, joined, cfg)
    if fused is None:
        return None
    raw, info, cams = fused
    if raw.empty:
        return None
    mesh, _ = clean_mesh(
        raw,
        min_component_fraction=cfg.min_component_fraction,
        min_component_diameter=cfg.min_component_diameter * info["radius"],
        smooth_iterations=cfg.smooth_iterations,
        taubin_lambda=cfg.taubin_lambda,
        taubin_mu=cfg.taubin_mu,
    )
    summary.mesh_frames = int(info["frames_used"])
    gt = case_ground_truth(ingest.gt_dir) if ingest.gt_dir else None
    gt_mesh = ground_truth_mesh(gt) if gt is not None else None
    if gt_mesh is not None and truth is not None:
        centre = gt.centerline() if hasattr(gt, "centerline") else None
        metrics = evaluate_against_gt(
            mesh,
            cams,  # type: ignore[arg-type]  (a case's cameras, by source_index)
            gt_mesh,
            {i: truth[i] for i in cams.c2w if i < len(truth)},
            info["depth_trunc"],
            cfg,
            gt_radius=float(np.mean(centre[1])) if centre is not None else None,
            est_radius=info["radius"],
        )
        if metrics.get("evaluated"):
            summary.chamfer_pct_radius = metrics.get("chamfer_pct_radius")
            summary.off_seen_pct = metrics.get("off_seen_pct")
    return mesh
