"""Where a signed-distance field starts: the lumen prior's wall (the tube or cavity prior as an
SDF prior), or without a wall a sphere of the typical viewing distance about every camera.

A signed distance moves its surface only as fast as its grid can change, so a surface that
starts far from the wall never reaches it: a sphere filling the scene box left the bench
colon at a training PSNR of 13 (28.9 with the density field). The starting distance is held
on a fixed coarse grid and the field learns a residual over it, so the surface starts where
the density field's prior terms pull it anyway and every step moves it a little.
"""

from __future__ import annotations

import numpy as np
import torch

from endopipe.stages.nerf.bounds import PriorBounds

#: Behind the wall the starting distance is cut here (scene units = radii): deep tissue never
#: renders, and a distance growing without bound there asks nothing of the residual.
DEEPEST = -1.0
#: Past the tube's ends: free space a little way from any surface (scene units), so that the
#: first steps, whose surface is wide (beta_init), can still draw one where the frames see it.
OPEN = 0.2


def starting_distance(pb: PriorBounds, cameras: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """d at scene points (N, 3), positive in free space: minus the prior's signed distance,
    or (no wall) the typical camera-to-point distance less the distance to the nearest
    camera (scene frame; `cameras` (C, 3) their centres)."""
    box, prior = pb.box, pb.prior
    if prior.kind != "none":
        w = box.scene_to_world(x).double()
        c = prior.closest(w, refine=False) if prior.kind == "tube" else None
        sd = c["dist"] - c["radius"] if c is not None else prior.signed_distance(w)
        d = -sd.to(x) / box.scale
        if c is not None and pb.cfg.sampling.open_tube_ends:
            # Past the curve's ends the wall is a straight guess: fade it out over a radius.
            past = torch.maximum(-c["s"], c["s"] - prior.length).clamp_min(0.0)
            fade = (past / c["radius"]).clamp(0.0, 1.0).to(x)
            d = (1.0 - fade) * d + fade * OPEN
    else:
        reach = pb.typical_distance() or 1.0
        d = reach - torch.cdist(x, cameras.to(x)).amin(1)
    return d.clamp_min(DEEPEST)


def start_grid(pb: PriorBounds, cameras: torch.Tensor, longest: int) -> torch.Tensor:
    """The starting distance at the nodes of a grid over the field's [-1, 1]^3 (`longest`
    nodes on the box's longest side), shaped (1, 1, D, H, W) for `grid_sample` (W along x)."""
    box = pb.box
    ext = np.asarray(box.extent, float)
    nodes = [int(max(8, round(longest * e / ext.max()))) for e in ext]
    axes = [np.linspace(-1.0, 1.0, n) for n in nodes]
    gz, gy, gx = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    g = np.stack([gx, gy, gz], -1).reshape(-1, 3)
    x = torch.as_tensor(box.world_to_scene_np(box.grid_to_world_np(g)), dtype=torch.float32)
    d = torch.cat([starting_distance(pb, cameras.cpu(), c) for c in x.split(1 << 16)])
    return d.view(1, 1, nodes[2], nodes[1], nodes[0]).float()
