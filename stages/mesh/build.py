"""The two ways the mesh stage builds its surface, wired from its config to the surface library:
TSDF fusion of 05_depth's maps, or marching cubes of the NeRF's density in the prior's band."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from endopipe.pipeline.errors import StageFailed
from endopipe.stages.mesh.config import MeshConfig
from endopipe.stages.mesh.inputs import depth_trunc, iter_depth_frames
from endopipe.stages.surface.marching import density_mesh, field_density_fn, iso_level
from endopipe.stages.surface.mesh import RawMesh
from endopipe.stages.surface.tsdf import tsdf_fuse

if TYPE_CHECKING:
    from endopipe.stages.depth.view import DepthView
    from endopipe.stages.nerf.view import NerfView
    from endopipe.stages.poses.view import PosesView


def fuse_depth(
    depth: DepthView,
    poses: PosesView,
    cfg: MeshConfig,
    radius: float,
    image: Callable[[int], np.ndarray] | None = None,
    c2w: dict[int, np.ndarray] | None = None,
) -> tuple[RawMesh, dict[str, float]]:
    """TSDF mesh of 05_depth's maps at the poses they were rendered at (`c2w`, from
    NerfView.c2w; default: cameras.json's): (mesh, info) where info has voxel_size, sdf_trunc,
    depth_trunc and frames_used."""
    voxel = cfg.voxel_size or radius / cfg.voxels_per_radius
    trunc = depth_trunc(depth, poses, cfg.depth_trunc, cfg.depth_trunc_percentile, cfg.min_opacity)
    frames = iter_depth_frames(depth, poses, cfg.min_opacity, image if cfg.colour else None, c2w)
    sdf_trunc = cfg.sdf_trunc_voxels * voxel
    mesh, used = tsdf_fuse(
        frames, poses.intrinsics, voxel, sdf_trunc, trunc, cfg.colour, cfg.min_observations
    )
    if used == 0:
        raise StageFailed(
            f"mesh: no registered frame has depth to fuse in {depth.folder}/depth (missing, or "
            "every pixel invalid, beyond depth_trunc or under min_opacity)"
        )
    info = {"voxel_size": voxel, "sdf_trunc": sdf_trunc, "depth_trunc": trunc, "frames_used": used}
    return mesh, info


def nerf_marching_cubes(
    nerf: NerfView, depth: DepthView, poses: PosesView, prior: Any, cfg: MeshConfig
) -> tuple[RawMesh, dict[str, float]]:
    """Marching cubes of the trained field's density (04_nerf) in the prior's band, over the
    registered cameras' frustums up to the depth truncation; iso-level calibrated on the field's
    rendered surface unless `cfg.density_level` is set."""
    from endopipe.stages.nerf.render import pick_device, surface_density_level

    trunc = depth_trunc(depth, poses, cfg.depth_trunc, cfg.depth_trunc_percentile, cfg.min_opacity)
    device = pick_device(cfg.device)
    model = nerf.model(device)
    fitted = nerf.c2w(poses)  # the poses the field was fitted to
    c2ws = [fitted[i] for i in poses.registered]
    calibrated = None
    if cfg.density_level is None:
        calibrated = surface_density_level(model, prior, poses.intrinsics, c2ws)
    radius = float(prior.typical_radius)
    mesh, info = density_mesh(
        field_density_fn(model),
        prior,
        c2ws,
        poses.intrinsics,
        trunc,
        iso_level(calibrated, cfg.density_level, radius),
        spacing=radius / cfg.mc_voxels_per_radius,
        band=cfg.band,
        chunk=cfg.chunk,
        device=device,
        cull=cfg.cull_unseen,
        cull_dilate=cfg.cull_dilate,
    )
    info["frames_used"] = len(c2ws)
    return mesh, info
