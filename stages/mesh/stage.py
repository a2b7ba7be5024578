"""mesh: a surface of the lumen from the depth maps (TSDF fusion) or the NeRF's density (marching
cubes), cleaned, exported in the world frame and units of 02_poses/cameras.json, and evaluated
against the case's ground-truth mesh when it has one (docs/formats.md).

- `tsdf`: the per-frame z-depth maps of 05_depth (0 = invalid; pixels whose 05_depth opacity is
  under `min_opacity` dropped) are fused in open3d's tensor VoxelBlockGrid (CPU). Voxel: the
  lumen radius (the prior's typical radius) / `voxels_per_radius`; truncation
  `sdf_trunc_voxels` voxels; depth truncated at `depth_trunc` (default: the
  `depth_trunc_percentile` percentile of all valid depths); surface where at least
  `min_observations` frames saw it. Vertex colours from the ingest frames when `colour`.
- `marching_cubes`: the NeRF density (stages.nerf's `load_model`) on a grid over the bounding
  box of the registered cameras' frustums (up to the same depth truncation), evaluated only in
  the prior's band |signed_distance| < `band` x radius; skimage's marching cubes at
  `density_level` (per lumen radius), keeping only surface on grid edges with both nodes in the
  band (no surface where the band ends); then, with `cull_unseen`, only the faces some
  registered camera sees (first hit of a pixel ray, on the lumen side, grown by `cull_dilate`
  rings): the NeRF's density often rises and falls again behind the wall, and that back
  surface is never seen.
- Clean-up: duplicated / null faces and unreferenced vertices removed, connected components
  smaller than `min_component_fraction` of the largest (faces) or `min_component_diameter`
  radii across dropped (floaters), then Taubin smoothing (pymeshlab).
- Evaluation (`evaluation.evaluate_against_gt`, over stages.surface.evaluate, which documents
  the crop): when cameras.json is metric the poses stage already put it in the GT world frame
  (mm): compared as is ("aligned": "gt_frame"); otherwise, with GT poses, the mesh is moved by
  the sim3 (Umeyama) taking the registered camera centres onto the GT ones ("sim3"). The
  cameras of the crop are the registered frames at their GT poses, the depth limit the fusion's
  depth truncation (in GT units). Results in metrics.json, flat keys.

The work is in the surface library (stages/surface/) and this folder's helpers (`inputs`,
`build`, `evaluation`); `Mesh.run` only wires them to the stage's inputs. 06_mesh is written
and read by `view.py` only.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from endopipe.pipeline.errors import StageFailed
from endopipe.pipeline.stage import Stage, StageContext
from endopipe.stages.centerline.view import CenterlineView
from endopipe.stages.depth.view import DepthView
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.ground_truth import poses_by_frame
from endopipe.stages.mesh.build import fuse_depth, nerf_marching_cubes
from endopipe.stages.mesh.config import MeshConfig
from endopipe.stages.mesh.evaluation import (
    case_ground_truth,
    evaluate_against_gt,
    ground_truth_mesh,
)
from endopipe.stages.mesh.metrics_file import MeshMetrics
from endopipe.stages.mesh.summary import MeshSummary
from endopipe.stages.mesh.view import MeshView, save_mesh, save_time_mesh
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import PosesView
from endopipe.stages.surface.clean import clean_mesh
from endopipe.stages.surface.mesh import RawMesh


def _finite(v: Any) -> Any:
    """JSON has no inf / nan: such values become null (also inside lists and dicts)."""
    if isinstance(v, float) and not np.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_finite(x) for x in v]
    return v


class Mesh(Stage):
    """Surface of the lumen: TSDF fusion of the depth maps (or NeRF marching cubes), cleaned."""

    name = "mesh"
    needs = ("ingest", "poses", "centerline", "nerf", "depth")
    version = 6  # 6: fused on the depth maps' own pixels; 5: a surface per chosen time
    Config = MeshConfig
    Summary = MeshSummary
    View = MeshView

    def run(self, ctx: StageContext[MeshConfig]) -> MeshSummary:
        cfg = ctx.config
        ingest = ctx.input(IngestView)
        poses = ctx.input(PosesView)
        centerline = ctx.input(CenterlineView)
        depth = ctx.input(DepthView)
        nerf = ctx.input(NerfView)
        prior = centerline.prior()
        radius = float(prior.typical_radius)
        if not poses.registered:
            raise StageFailed("mesh: no registered frame in 02_poses")

        t0 = time.perf_counter()
        if cfg.method == "tsdf":
            c2w = every = nerf.c2w(poses)  # the poses the depth maps were rendered at
            if nerf.dynamic:  # a scene that moves: one time's surface
                frame = poses.registered[0] if cfg.frame is None else cfg.frame
                if frame not in c2w:
                    raise StageFailed(f"mesh.frame {frame} has no pose; pick a registered frame")
                c2w = {frame: c2w[frame]}
                ctx.log(f"a scene that moves: the mesh is frame {frame}'s surface (mesh.frame)")
            raw, info = fuse_depth(depth, poses, cfg, radius, ingest.image, c2w)
        else:
            raw, info = nerf_marching_cubes(nerf, depth, poses, prior, cfg)
        build_s = time.perf_counter() - t0
        ctx.log(
            f"{cfg.method}: {len(raw.vertices):,} vertices, {len(raw.faces):,} faces before "
            f"clean-up (voxel {info['voxel_size']:.3g}, depth_trunc {info['depth_trunc']:.3g}) "
            f"in {build_s:.1f} s"
        )
        if raw.empty:
            raise StageFailed(
                "mesh: the surface is empty"
                + (" (try another density_level)" if cfg.method == "marching_cubes" else "")
            )

        t1 = time.perf_counter()
        mesh, clean_info = cleaned(raw, cfg, radius)
        clean_s = time.perf_counter() - t1
        ctx.log(
            f"clean-up: {clean_info['components_removed']} small components removed; mesh.ply: "
            f"{len(mesh.vertices):,} vertices, {len(mesh.faces):,} faces"
        )
        save_mesh(ctx.out, mesh, obj=cfg.export_obj)
        time_frames: list[int] = []
        if cfg.method == "tsdf" and nerf.dynamic and cfg.times:
            time_frames = mesh_times(ctx, depth, poses, ingest, every, radius)

        evaluation: dict[str, Any] = {"evaluated": False}
        centres = poses.centres()
        no_path = len(centres) > 1 and float(np.ptp(centres, axis=0).max()) == 0.0
        if no_path and not poses.metric:
            # no path to align on the truth's: the relative units have no scale to compare
            evaluation["reason"] = "a still camera's mesh is in relative units (no scale)"
        elif cfg.evaluate:
            gt = case_ground_truth(ctx.case.gt_dir or ingest.gt_dir)
            gt_mesh = ground_truth_mesh(gt)
            if gt_mesh is not None:
                truth = gt.centerline() if hasattr(gt, "centerline") else None
                evaluation = evaluate_against_gt(
                    mesh,
                    poses,
                    gt_mesh,
                    poses_by_frame(gt, ingest.frames),
                    info["depth_trunc"],
                    cfg,
                    gt_radius=float(np.mean(truth[1])) if truth is not None else None,
                    est_radius=float(np.mean(centerline.radius))
                    if centerline.kind == "tube"
                    else radius,
                    fov_mask=ingest.fov(),
                )
                evaluation["gt_kind"] = getattr(gt, "kind", "exact")
                if evaluation["evaluated"]:  # before inf / nan become null: the log shows them
                    ctx.log(
                        f"vs gt ({evaluation['aligned']}): chamfer {evaluation['chamfer']:.3f} "
                        f"({evaluation['chamfer_pct_radius']:.2f}% of radius), F@"
                        f"{evaluation['threshold']:.2g} {evaluation['fscore']:.3f}"
                    )
            else:
                evaluation["reason"] = "no ground-truth mesh"
        evaluation.update(
            method=cfg.method,
            vertices=int(len(mesh.vertices)),
            faces=int(len(mesh.faces)),
            raw_vertices=int(len(raw.vertices)),
            raw_faces=int(len(raw.faces)),
            **{k: v if isinstance(v, int) else float(v) for k, v in info.items()},
            **clean_info,
        )
        metrics = MeshMetrics.model_validate(_finite(evaluation))
        metrics.write(ctx.out)
        return MeshSummary(
            method=cfg.method,
            vertices=len(mesh.vertices),
            faces=len(mesh.faces),
            voxel_size=float(info["voxel_size"]),
            depth_trunc=float(info["depth_trunc"]),
            frames_used=int(info["frames_used"]),
            units=poses.file.units,
            build_s=round(build_s, 2),
            clean_s=round(clean_s, 2),
            evaluated=metrics.evaluated,
            threshold=metrics.threshold,
            aligned=metrics.aligned,
            chamfer=metrics.chamfer,
            chamfer_pct_radius=metrics.chamfer_pct_radius,
            accuracy=metrics.accuracy,
            completeness=metrics.completeness,
            fscore=metrics.fscore,
            off_seen_pct=metrics.off_seen_pct,
            time_frames=time_frames,
        )


def cleaned(raw: RawMesh, cfg: MeshConfig, radius: float) -> tuple[RawMesh, dict]:
    """The clean-up every surface of the stage gets (floaters dropped, Taubin smoothing)."""
    return clean_mesh(
        raw,
        min_component_fraction=cfg.min_component_fraction,
        min_component_diameter=cfg.min_component_diameter * radius,
        smooth_iterations=cfg.smooth_iterations,
        taubin_lambda=cfg.taubin_lambda,
        taubin_mu=cfg.taubin_mu,
    )


def mesh_times(
    ctx: StageContext[MeshConfig],
    depth: DepthView,
    poses: PosesView,
    ingest: IngestView,
    c2w: dict[int, np.ndarray],
    radius: float,
) -> list[int]:
    """A scene that moves: each of `mesh.times` frames, spread evenly over the registered ones,
    gets its own surface from its depth alone (times/), cleaned as mesh.ply is. A frame whose
    surface comes out empty is said and skipped."""
    cfg = ctx.config
    frames = [f for f in poses.registered if f in c2w]
    picks = np.unique(np.round(np.linspace(0, len(frames) - 1, min(cfg.times, len(frames)))))
    done = []
    for k in picks.astype(int):
        frame = frames[k]
        raw, _ = fuse_depth(depth, poses, cfg, radius, ingest.image, {frame: c2w[frame]})
        if raw.empty:
            ctx.log(f"frame {frame}: no surface at its time")
            continue
        mesh, _ = cleaned(raw, cfg, radius)
        save_time_mesh(ctx.out, frame, mesh)
        done.append(frame)
    ctx.log(f"a surface at each of frames {', '.join(map(str, done))}: 06_mesh/times/")
    return done
