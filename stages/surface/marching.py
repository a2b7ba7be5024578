"""Iso-surface of a density field inside a prior's band around the lumen wall: the density on a
grid (only where the band is), skimage's marching cubes, and the seen-surface cull.

The density is a plain callable `density_fn(points (N, 3) world, torch) -> sigma (N,)` per world
unit (`field_density_fn` adapts a NeRF-like field); the prior is anything with
`signed_distance`, `radius_at` (torch, per point) and `typical_radius`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from endopipe.pipeline.errors import StageFailed
from endopipe.stages.camera import Camera
from endopipe.stages.surface.clean import cull_unseen
from endopipe.stages.surface.evaluate import frustum_box
from endopipe.stages.surface.mesh import RawMesh

if TYPE_CHECKING:
    import torch

DensityFn = Callable[["torch.Tensor"], "torch.Tensor"]

#: Iso-level (per lumen radius) when the field gives no calibration (no opaque ray).
DEFAULT_DENSITY_LEVEL = 3.0
#: Grid nodes beyond which the band grid is refused (memory).
MAX_GRID_NODES = 400_000_000


class BandPrior(Protocol):
    """What the band needs of a lumen prior (stages.centerline's priors have it)."""

    typical_radius: float

    def signed_distance(self, points: torch.Tensor) -> torch.Tensor: ...

    def radius_at(self, points: torch.Tensor) -> torch.Tensor: ...


@dataclass
class BandGrid:
    """Density on a regular grid: values[i, j, k] at origin + (i, j, k) * spacing; `mask`:
    nodes in the prior's band (values elsewhere are 0 and not used)."""

    values: np.ndarray
    mask: np.ndarray
    origin: np.ndarray
    spacing: float


def field_density_fn(field: Any) -> DensityFn:
    """density_fn(points (N, 3) world) -> sigma (N,) per world unit, of a field that works in a
    normalised scene box (`field.box.world_to_scene`, `field.box.scale`,
    `field.density_scene`: stages.nerf's models)."""
    box = field.box

    def fn(points: torch.Tensor) -> torch.Tensor:
        return field.density_scene(box.world_to_scene(points)) / box.scale

    return fn


def iso_level(calibrated: float | None, per_radius: float | None, radius: float) -> float:
    """The iso-level per world unit: `calibrated` when known, else `per_radius` (default
    DEFAULT_DENSITY_LEVEL) per lumen radius."""
    if calibrated is not None:
        return calibrated
    return (per_radius or DEFAULT_DENSITY_LEVEL) / radius


def band_density_grid(
    density_fn: DensityFn,
    prior: BandPrior,
    lo: np.ndarray,
    hi: np.ndarray,
    spacing: float,
    band: float,
    chunk: int = 1 << 18,
    device: str | torch.device = "cpu",
) -> BandGrid:
    """`density_fn` on the grid over [lo, hi] with `spacing`, only at nodes within `band` x
    radius of the prior's wall (|signed_distance| < band * radius_at)."""
    import torch

    lo = np.asarray(lo, np.float64)
    shape = tuple(int(np.floor((hi[i] - lo[i]) / spacing)) + 1 for i in range(3))
    if np.prod(shape, dtype=np.int64) > MAX_GRID_NODES:
        raise StageFailed(
            f"mesh: marching-cubes grid {shape} is too large; lower mc_voxels_per_radius "
            "or depth_trunc"
        )
    values = np.zeros(shape, np.float32)
    mask = np.zeros(shape, bool)
    axes = [lo[i] + spacing * np.arange(shape[i]) for i in range(3)]
    yz = np.stack(np.meshgrid(axes[1], axes[2], indexing="ij"), -1).reshape(-1, 2)
    plane = len(yz)
    step = max(1, chunk // plane)
    for i0 in range(0, shape[0], step):
        xs = axes[0][i0 : i0 + step]
        pts = np.concatenate([np.repeat(xs, plane)[:, None], np.tile(yz, (len(xs), 1))], axis=1)
        pts_t = torch.as_tensor(pts, dtype=torch.float32)
        with torch.no_grad():
            sd = prior.signed_distance(pts_t).float()
            rad = prior.radius_at(pts_t).float()
        inside = (sd.abs() < band * rad).cpu().numpy()
        sigma = np.zeros(len(pts), np.float32)
        idx = np.nonzero(inside)[0]
        for a in range(0, len(idx), chunk):
            sel = idx[a : a + chunk]
            with torch.no_grad():
                s = density_fn(pts_t[sel].to(device))
            sigma[sel] = s.float().cpu().numpy().reshape(-1)
        values[i0 : i0 + len(xs)] = sigma.reshape(len(xs), shape[1], shape[2])
        mask[i0 : i0 + len(xs)] = inside.reshape(len(xs), shape[1], shape[2])
    return BandGrid(values, mask, lo, float(spacing))


def marching_cubes_mesh(grid: BandGrid, level: float) -> RawMesh:
    """Iso-surface at `level` from grid edges whose two nodes both lie in the grid's mask (no
    surface where the band ends); faces wound so that normals point towards lower density
    (into the lumen)."""
    from skimage.measure import marching_cubes

    v, m = grid.values, grid.mask
    empty = RawMesh.empty_mesh()
    if min(v.shape) < 2 or not m.any():
        return empty
    vals = v[m]
    if not (vals.min() < level < vals.max()):
        return empty
    # skimage's mask restricts the cubes visited (by their first corner; a speed-up only).
    verts, faces, _, _ = marching_cubes(v, level=level, mask=m, allow_degenerate=False)
    if len(faces) == 0:
        return empty
    # A vertex lies on a grid edge: both end nodes must be in the band, else drop its faces.
    lo = np.clip(np.floor(verts + 1e-6).astype(np.int64), 0, np.array(v.shape) - 1)
    hi = np.clip(np.ceil(verts - 1e-6).astype(np.int64), 0, np.array(v.shape) - 1)
    ok_v = m[lo[:, 0], lo[:, 1], lo[:, 2]] & m[hi[:, 0], hi[:, 1], hi[:, 2]]
    faces = faces[ok_v[faces].all(1)][:, ::-1]  # skimage winds normals towards high density
    used, faces = np.unique(faces, return_inverse=True)
    verts = verts[used].astype(np.float64) * grid.spacing + grid.origin
    return RawMesh(verts, faces.reshape(-1, 3).astype(np.int64))


def density_mesh(
    density_fn: DensityFn,
    prior: BandPrior,
    c2ws: list[np.ndarray],
    camera: Camera,
    depth_trunc: float,
    level: float,
    *,
    spacing: float,
    band: float,
    chunk: int = 1 << 18,
    device: str | torch.device = "cpu",
    cull: bool = True,
    cull_dilate: int = 1,
) -> tuple[RawMesh, dict[str, float]]:
    """Marching cubes of a density function at `level` (per world unit) in the prior's band,
    over the box of the cameras' frustums up to `depth_trunc`; with `cull`, only the faces the
    cameras see (`cull_unseen`). Returns the mesh and what was done (voxel_size, depth_trunc,
    level, band_nodes, faces_extracted, seen_fraction)."""
    lo, hi = frustum_box(c2ws, camera, depth_trunc)
    grid = band_density_grid(density_fn, prior, lo, hi, spacing, band, chunk, device)
    mesh = marching_cubes_mesh(grid, level)
    info = {
        "voxel_size": spacing,
        "depth_trunc": depth_trunc,
        "level": level,
        "band_nodes": int(grid.mask.sum()),
        "faces_extracted": len(mesh.faces),
    }
    if cull:
        mesh, info["seen_fraction"] = cull_unseen(mesh, c2ws, camera, 1, cull_dilate)
    return mesh, info
