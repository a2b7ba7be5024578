"""mesh: a surface of the lumen from the depth maps (TSDF fusion) or the NeRF's density (marching
cubes), cleaned, exported in the world frame and units of 02_poses/cameras.json, and evaluated
against the case's ground-truth mesh when it has one (DESIGN §3 `06_mesh/`, §6).

- `tsdf`: the per-frame z-depth maps of 05_depth (0 = invalid; pixels whose 05_depth opacity is
  under `min_opacity` dropped) are fused in open3d's tensor VoxelBlockGrid (CPU). Voxel: the
  lumen radius (the prior's typical radius) / `voxels_per_radius`; truncation
  `sdf_trunc_voxels` voxels; depth truncated at `depth_trunc` (default: the
  `depth_trunc_percentile` percentile of all valid depths); surface where at least
  `min_observations` frames saw it. Vertex colours from the ingest frames when `colour`.
- `marching_cubes`: the NeRF density (a `density_fn(points (N, 3) world, torch) -> sigma (N,)
  per world unit`, here from stages.nerf's `load_model`) on a grid over the bounding box of the
  registered cameras' frustums (up to the same depth truncation), evaluated only in the prior's
  band |signed_distance| < `band` x radius; skimage's marching cubes at `density_level` (per
  lumen radius), keeping only surface on grid edges with both nodes in the band (no surface
  where the band ends); then, with `cull_unseen`, only the faces some registered camera sees
  (first hit of a pixel ray, on the lumen side, grown by `cull_dilate` rings): the NeRF's
  density often rises and falls again behind the wall, and that back surface is never seen.
- Clean-up: duplicated / null faces and unreferenced vertices removed, connected components
  smaller than `min_component_fraction` of the largest (faces) or `min_component_diameter`
  radii across dropped (floaters), then Taubin smoothing (pymeshlab).
- Evaluation (stages/mesh_metrics.py `evaluate_mesh`, which documents the crop): when
  cameras.json is metric the poses stage already put it in the GT world frame (mm):
  compared as is ("aligned": "gt_frame"); otherwise, with GT poses, the mesh is moved by the
  sim3 (Umeyama) taking the registered camera centres onto the GT ones ("sim3"). The cameras
  of the crop are the registered frames at their GT poses, the depth limit the fusion's
  depth truncation (in GT units). Results in metrics.json, flat keys.

The work is plain functions over arrays and folders (`fuse_depth_folder`, `tsdf_fuse`,
`band_density_grid`, `marching_cubes_mesh`, `clean_mesh`, `evaluate_against_gt`); `Mesh.run`
only wires them to the stage's inputs.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from pydantic import Field

from endopipe.pipeline.errors import StageFailed
from endopipe.pipeline.stage import Stage, StageConfig, StageContext, Summary, write_json
from endopipe.stages.camera import Camera, umeyama
from endopipe.stages.poses.view import PosesView
from endopipe.stages.surface.evaluate import evaluate_mesh, frustum_box, transform_points

DensityFn = Callable[[torch.Tensor], torch.Tensor]


class MeshConfig(StageConfig):
    method: Literal["tsdf", "marching_cubes"] = Field(
        "tsdf",
        description="tsdf: fuse the depth maps of 05_depth (open3d); marching_cubes: iso-surface "
        "of the NeRF density in the prior's band around the lumen wall.",
    )
    voxels_per_radius: float = Field(
        64.0, gt=0, description="TSDF voxel size = lumen radius (the prior's) / this."
    )
    voxel_size: float | None = Field(
        None, gt=0, description="TSDF voxel size in cameras.json units; overrides the above."
    )
    sdf_trunc_voxels: float = Field(4.0, gt=1, description="TSDF truncation distance, in voxels.")
    depth_trunc: float | None = Field(
        None,
        gt=0,
        description="Ignore depths beyond this (cameras.json units); also the depth limit of "
        "the evaluation crop and of the marching-cubes grid. None: from the data (below).",
    )
    depth_trunc_percentile: float = Field(
        95.0,
        gt=0,
        le=100,
        description="When depth_trunc is None: this percentile of all valid depths.",
    )
    min_opacity: float = Field(
        0.5,
        ge=0,
        le=1,
        description="Drop pixels whose 05_depth opacity is below this (when opacity maps exist).",
    )
    min_observations: int = Field(
        1, ge=1, description="TSDF: frames that must observe a voxel for it to be surface."
    )
    colour: bool = Field(True, description="TSDF: vertex colours from the ingest frames.")
    mc_voxels_per_radius: float = Field(
        32.0, gt=0, description="Marching cubes: grid spacing = lumen radius / this."
    )
    band: float = Field(
        0.6,
        gt=0,
        description="Marching cubes: evaluate the density where |prior signed distance| < "
        "band x local radius (elsewhere nothing is extracted).",
    )
    density_level: float | None = Field(
        None,
        gt=0,
        description="Marching cubes: iso-level of the density, per lumen radius (the NeRF's "
        "scene units; sigma in world units = level / radius). None: calibrated from the field, "
        "the density at its rendered surface (a fixed level sits in front of it).",
    )
    cull_unseen: bool = Field(
        True,
        description="Marching cubes: keep only faces that a registered camera's pixel ray hits "
        "first, on their lumen side (drops surface behind the wall and never-seen parts).",
    )
    cull_dilate: int = Field(
        1, ge=0, description="Marching cubes: grow the seen faces by this many rings (no holes)."
    )
    device: Literal["auto", "cpu", "cuda"] = Field(
        "auto", description="Marching cubes: where the NeRF density is evaluated."
    )
    chunk: int = Field(
        1 << 18, ge=1024, description="Marching cubes: points per density evaluation."
    )
    min_component_fraction: float = Field(
        0.05,
        ge=0,
        le=1,
        description="Drop connected components with fewer faces than this x the largest's.",
    )
    min_component_diameter: float = Field(
        0.5,
        ge=0,
        description="Drop connected components whose bounding-box diagonal is under this many "
        "lumen radii (floaters).",
    )
    smooth_iterations: int = Field(5, ge=0, description="Taubin smoothing steps (0: none).")
    taubin_lambda: float = Field(0.5, gt=0, lt=1, description="Taubin smoothing lambda.")
    taubin_mu: float = Field(-0.53, lt=0, gt=-1, description="Taubin smoothing mu (negative).")
    export_obj: bool = Field(False, description="Also write mesh.obj (same frame and units).")
    evaluate: bool = Field(
        True, description="Compare with the case's gt/mesh.ply when it exists (metrics.json)."
    )
    eval_samples: int = Field(
        200_000, ge=1000, description="Points sampled on each surface for the evaluation."
    )
    eval_occlusion: bool = Field(
        True,
        description="Evaluation crop: GT surface counts only where it is the first hit from a "
        "camera (hidden behind folds: not asked for). Off: everything in the frustums.",
    )
    fscore_threshold: float = Field(
        1.0, gt=0, description="F-score distance threshold, in GT units (mm)."
    )
    fscore_threshold_pct_radius: float | None = Field(
        None,
        gt=0,
        description="When set: the F-score threshold is this % of the mean lumen radius instead.",
    )


class MeshSummary(Summary):
    method: str
    vertices: int
    faces: int
    voxel_size: float
    depth_trunc: float
    frames_used: int
    units: str
    build_s: float
    clean_s: float
    evaluated: bool = False
    chamfer: float | None = None
    chamfer_pct_radius: float | None = None
    accuracy: float | None = None
    completeness: float | None = None
    fscore: float | None = None
    threshold: float | None = None
    aligned: str | None = None


@dataclass
class RawMesh:
    """Triangle mesh arrays: vertices (V, 3) float64, faces (F, 3) int64, colours (V, 3) uint8."""

    vertices: np.ndarray
    faces: np.ndarray
    colours: np.ndarray | None = None

    @property
    def empty(self) -> bool:
        return len(self.faces) == 0

    @classmethod
    def empty_mesh(cls) -> RawMesh:
        return cls(np.zeros((0, 3)), np.zeros((0, 3), np.int64))


@dataclass
class DepthFrame:
    index: int
    depth: np.ndarray  # HxW float32 z-depth, 0 = invalid
    c2w: np.ndarray  # 4x4
    rgb: np.ndarray | None = None  # HxWx3 uint8, same size as depth


# --- inputs ------------------------------------------------------------------------------------
def depth_path(depth_dir: Path, index: int) -> Path:
    return Path(depth_dir) / "depth" / f"{index:06d}.npy"


def load_depth(depth_dir: Path, index: int, min_opacity: float = 0.0) -> np.ndarray | None:
    """05_depth z-depth of frame `index` (0 = invalid), with low-opacity pixels zeroed; None when
    the frame has no depth map."""
    path = depth_path(depth_dir, index)
    if not path.is_file():
        return None
    depth = np.load(path).astype(np.float32)
    depth[~np.isfinite(depth) | (depth < 0)] = 0.0
    op_path = Path(depth_dir) / "opacity" / f"{index:06d}.npy"
    if min_opacity > 0 and op_path.is_file():
        opacity = np.load(op_path)
        if opacity.shape == depth.shape:
            depth[opacity < min_opacity] = 0.0
    return depth


def auto_depth_trunc(depths: Iterable[np.ndarray], percentile: float) -> float:
    """The `percentile` percentile of all valid (> 0) depth values (subsampled)."""
    vals = [d[d > 0][::7] for d in depths]
    vals = [v for v in vals if len(v)]
    if not vals:
        raise StageFailed("mesh: the depth maps have no valid pixel")
    return float(np.percentile(np.concatenate(vals), percentile))


def iter_depth_frames(
    depth_dir: Path,
    poses: PosesView,
    min_opacity: float,
    image: Callable[[int], np.ndarray] | None = None,
) -> Iterator[DepthFrame]:
    """The registered frames that have a depth map, with colour from `image(index)` (RGB)."""
    import cv2

    for i in poses.registered:
        depth = load_depth(depth_dir, i, min_opacity)
        if depth is None:
            continue
        rgb = None
        if image is not None:
            rgb = image(i)
            if rgb.shape[:2] != depth.shape:
                rgb = cv2.resize(rgb, depth.shape[::-1], interpolation=cv2.INTER_AREA)
        yield DepthFrame(i, depth, poses.c2w[i], rgb)


# --- TSDF fusion -----------------------------------------------------------------------------
def tsdf_fuse(
    frames: Iterable[DepthFrame],
    intrinsics: Camera,
    voxel: float,
    sdf_trunc: float,
    depth_trunc: float,
    colour: bool = True,
    min_observations: int = 1,
    block_resolution: int = 16,
) -> tuple[RawMesh, int]:
    """TSDF fusion of z-depth maps (open3d's tensor VoxelBlockGrid, CPU); returns the mesh and
    the number of frames integrated. Depth maps may have another size than `intrinsics`
    (scaled). A voxel needs `min_observations` frames to be part of the surface.

    (open3d 0.20's legacy ScalableTSDFVolume extracts empty meshes: not used.)"""
    import open3d as o3d
    import open3d.core as o3c

    cpu = o3c.Device("CPU:0")
    f32 = o3c.float32
    names, dtypes, channels = ["tsdf", "weight"], [f32, f32], [1, 1]
    if colour:
        names.append("color")
        dtypes.append(f32)
        channels.append(3)
    vbg = o3d.t.geometry.VoxelBlockGrid(
        attr_names=tuple(names),
        attr_dtypes=tuple(dtypes),
        attr_channels=tuple(channels),
        voxel_size=float(voxel),
        block_resolution=int(block_resolution),
        block_count=1000,  # grows on demand
        device=cpu,
    )
    mult = float(sdf_trunc) / float(voxel)
    used = 0
    for fr in frames:
        if not ((fr.depth > 0) & (fr.depth < depth_trunc)).any():
            continue  # nothing to fuse (open3d raises on a frame that touches no block)
        h, w = fr.depth.shape
        k = intrinsics
        if (w, h) != (k.width, k.height):
            k = k.scaled(w, h)
        K = o3c.Tensor(k.matrix())
        w2c = o3c.Tensor(np.linalg.inv(np.asarray(fr.c2w, np.float64)))
        depth = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(fr.depth, np.float32)))
        try:
            blocks = vbg.compute_unique_block_coordinates(
                depth, K, w2c, 1.0, float(depth_trunc), trunc_voxel_multiplier=mult
            )
        except RuntimeError as e:  # a few scattered pixels can touch no block either
            if "No block is touched" in str(e):
                continue
            raise
        if colour:
            rgb = fr.rgb if fr.rgb is not None else np.full((h, w, 3), 128, np.uint8)
            img = o3d.t.geometry.Image(
                o3c.Tensor(np.ascontiguousarray(rgb, np.float32) / np.float32(255.0))
            )
            vbg.integrate(
                blocks, depth, img, K, K, w2c, 1.0, float(depth_trunc), trunc_voxel_multiplier=mult
            )
        else:
            vbg.integrate(
                blocks, depth, K, w2c, 1.0, float(depth_trunc), trunc_voxel_multiplier=mult
            )
        used += 1
    if used == 0:
        return RawMesh.empty_mesh(), 0
    try:
        m = vbg.extract_triangle_mesh(weight_threshold=float(min_observations) - 0.5)
    except RuntimeError as e:  # open3d fails instead of returning an empty mesh
        if "has shape {0}" in str(e):
            return RawMesh.empty_mesh(), used
        raise
    verts = m.vertex.positions.numpy().astype(np.float64)
    faces = (
        m.triangle.indices.numpy().astype(np.int64)
        if "indices" in m.triangle
        else np.zeros((0, 3), np.int64)
    )
    colours = None
    if colour and "colors" in m.vertex:
        colours = np.clip(m.vertex.colors.numpy() * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return RawMesh(verts, faces, colours), used


def fuse_depth_folder(
    depth_dir: Path,
    poses: PosesView,
    cfg: MeshConfig,
    radius: float,
    image: Callable[[int], np.ndarray] | None = None,
) -> tuple[RawMesh, dict[str, float]]:
    """TSDF mesh of a 05_depth folder with the poses of cameras.json: (mesh, info) where info
    has voxel_size, sdf_trunc, depth_trunc and frames_used."""
    voxel = cfg.voxel_size or radius / cfg.voxels_per_radius
    trunc = cfg.depth_trunc
    if trunc is None:
        trunc = auto_depth_trunc(
            (d.depth for d in iter_depth_frames(depth_dir, poses, cfg.min_opacity)),
            cfg.depth_trunc_percentile,
        )
    frames = iter_depth_frames(depth_dir, poses, cfg.min_opacity, image if cfg.colour else None)
    sdf_trunc = cfg.sdf_trunc_voxels * voxel
    mesh, used = tsdf_fuse(
        frames, poses.intrinsics, voxel, sdf_trunc, trunc, cfg.colour, cfg.min_observations
    )
    if used == 0:
        raise StageFailed(
            f"mesh: no registered frame has depth to fuse in {depth_dir}/depth (missing, or "
            "every pixel invalid, beyond depth_trunc or under min_opacity)"
        )
    info = {"voxel_size": voxel, "sdf_trunc": sdf_trunc, "depth_trunc": trunc, "frames_used": used}
    return mesh, info


# --- marching cubes on the NeRF density -------------------------------------------------------
@dataclass
class BandGrid:
    """Density on a regular grid: values[i, j, k] at origin + (i, j, k) * spacing; `mask`:
    nodes in the prior's band (values elsewhere are 0 and not used)."""

    values: np.ndarray
    mask: np.ndarray
    origin: np.ndarray
    spacing: float


def band_density_grid(
    density_fn: DensityFn,
    prior: Any,
    lo: np.ndarray,
    hi: np.ndarray,
    spacing: float,
    band: float,
    chunk: int = 1 << 18,
    device: str | torch.device = "cpu",
) -> BandGrid:
    """`density_fn` on the grid over [lo, hi] with `spacing`, only at nodes within `band` x
    radius of the prior's wall (|signed_distance| < band * radius_at)."""
    lo = np.asarray(lo, np.float64)
    shape = tuple(int(np.floor((hi[i] - lo[i]) / spacing)) + 1 for i in range(3))
    if np.prod(shape, dtype=np.int64) > 400_000_000:
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


def cull_unseen(
    mesh: RawMesh,
    c2ws: list[np.ndarray],
    intrinsics: Camera,
    supersample: int = 1,
    dilate: int = 1,
) -> tuple[RawMesh, float]:
    """Keep the faces that some camera sees: the first hit of one of its pixel rays
    (`supersample`^2 rays per pixel), on the face's front (normals face the lumen), then grown
    by `dilate` rings of neighbouring faces (closes the pin holes between rays). Returns the
    mesh and the fraction of faces kept."""
    import open3d as o3d

    from endopipe.stages.surface.evaluate import _raycasting_scene

    if mesh.empty:
        return mesh, 1.0
    v, f = mesh.vertices, mesh.faces
    centre = v.mean(0)
    scene = _raycasting_scene(v - centre, f)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    k = intrinsics
    if supersample > 1:
        k = k.scaled(k.width * supersample, k.height * supersample)
    u, w = np.meshgrid(np.arange(k.width, dtype=np.float64), np.arange(k.height, dtype=np.float64))
    dirs_cam = np.stack([(u - k.cx) / k.fx, (w - k.cy) / k.fy, np.ones_like(u)], -1).reshape(-1, 3)
    seen = np.zeros(len(f), bool)
    invalid = o3d.t.geometry.RaycastingScene.INVALID_ID
    for c2w in c2ws:
        c2w = np.asarray(c2w, np.float64)
        d = dirs_cam @ c2w[:3, :3].T
        o = np.broadcast_to(c2w[:3, 3] - centre, d.shape)
        rays = o3d.core.Tensor(np.ascontiguousarray(np.concatenate([o, d], 1), np.float32))
        ids = scene.cast_rays(rays)["primitive_ids"].numpy().astype(np.int64)
        hit = ids != invalid
        ids, d = ids[hit], d[hit]
        front = (n[ids] * d).sum(1) < 0
        seen[ids[front]] = True
    for _ in range(max(dilate, 0)):
        vs = np.zeros(len(v), bool)
        vs[f[seen].ravel()] = True
        seen = vs[f].any(1)
    return RawMesh(v, f[seen], mesh.colours), float(seen.mean())


#: Iso-level (per lumen radius) when the field gives no calibration (no opaque ray).
DEFAULT_DENSITY_LEVEL = 3.0


def nerf_density_fn(model: Any) -> DensityFn:
    """density_fn(points (N, 3) world) -> sigma (N,) per world unit, of a stages.nerf model."""
    box = model.box

    def fn(points: torch.Tensor) -> torch.Tensor:
        return model.density_scene(box.world_to_scene(points)) / box.scale

    return fn


def density_mesh(
    density_fn: DensityFn,
    prior: Any,
    c2ws: list[np.ndarray],
    intrinsics: Camera,
    cfg: MeshConfig,
    depth_trunc: float,
    device: str | torch.device = "cpu",
    level: float | None = None,
) -> tuple[RawMesh, dict[str, float]]:
    """Marching cubes of a density function in the prior's band, over the frustums' box, at
    `level` (per world unit; None: cfg.density_level)."""
    radius = float(prior.typical_radius)
    spacing = radius / cfg.mc_voxels_per_radius
    k = intrinsics
    lo, hi = frustum_box(c2ws, k.matrix(), k.width, k.height, depth_trunc)
    grid = band_density_grid(density_fn, prior, lo, hi, spacing, cfg.band, cfg.chunk, device)
    if level is None:
        level = (cfg.density_level or DEFAULT_DENSITY_LEVEL) / radius
    mesh = marching_cubes_mesh(grid, level)
    info = {
        "voxel_size": spacing,
        "depth_trunc": depth_trunc,
        "level": level,
        "band_nodes": int(grid.mask.sum()),
        "faces_extracted": len(mesh.faces),
    }
    if cfg.cull_unseen:
        mesh, info["seen_fraction"] = cull_unseen(mesh, c2ws, intrinsics, 1, cfg.cull_dilate)
    return mesh, info


# --- clean-up ----------------------------------------------------------------------------------
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


def write_mesh(path: Path, mesh: RawMesh) -> None:
    """PLY (binary) or OBJ by the suffix, vertex colours when present."""
    import trimesh

    tm = trimesh.Trimesh(
        vertices=mesh.vertices,
        faces=mesh.faces,
        vertex_colors=mesh.colours,
        process=False,
    )
    tm.export(str(path))


def read_mesh(path: Path) -> RawMesh:
    import trimesh

    tm = trimesh.load(str(path), process=False, force="mesh")
    colours = None
    vc = getattr(tm.visual, "vertex_colors", None)
    if vc is not None and len(vc) == len(tm.vertices):
        colours = np.asarray(vc)[:, :3].astype(np.uint8)
    return RawMesh(np.asarray(tm.vertices, np.float64), np.asarray(tm.faces, np.int64), colours)


# --- evaluation -------------------------------------------------------------------------------
#: Bands of the distance to the nearest camera centre, in lumen radii, for metrics.json's
#: by_camera_distance (the last band is open).
DISTANCE_BANDS_RADII = (0.0, 1.0, 1.5, 2.0, 3.0, float("inf"))


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

    `gt_poses`: GT c2w per endopipe frame index (None: none known). Metric cameras.json: already
    in the GT frame; else sim3 (Umeyama) of the registered centres onto the GT centres. The crop
    cameras are the registered frames at their GT poses (the aligned estimates when no GT pose),
    the depth limit `depth_trunc` x the sim3 scale. Radius for chamfer_pct_radius: `gt_radius`
    (gt/centerline.json), else `est_radius` (cameras.json units) x scale.
    """
    common = sorted(set(poses.registered) & set(gt_poses or {}))
    if poses.metric:
        s, R, t, aligned = 1.0, np.eye(3), np.zeros(3), "gt_frame"
    elif len(common) >= 3:
        src = np.array([poses.c2w[i][:3, 3] for i in common])
        dst = np.array([gt_poses[i][:3, 3] for i in common])  # type: ignore[index]
        s, R, t = umeyama(src, dst, with_scale=True)
        aligned = "sim3"
    else:
        return {"evaluated": False, "reason": "cameras not metric and fewer than 3 GT poses"}

    import trimesh

    gt = trimesh.load(str(gt_mesh_path), process=False, force="mesh")
    verts = transform_points(mesh.vertices, s, R, t)
    cams = []
    for i in poses.registered:
        if gt_poses is not None and i in gt_poses:
            cams.append(np.asarray(gt_poses[i], np.float64))
        else:
            c = np.eye(4)
            c[:3, :3] = R @ poses.c2w[i][:3, :3]
            c[:3, 3] = s * R @ poses.c2w[i][:3, 3] + t
            cams.append(c)
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
        np.asarray(gt.vertices),
        np.asarray(gt.faces),
        cams,
        k.matrix(),
        k.width,
        k.height,
        depth_trunc * s,
        threshold,
        mask=mask,
        n_samples=cfg.eval_samples,
        occlusion=cfg.eval_occlusion,
        distance_bands=[b * radius for b in DISTANCE_BANDS_RADII] if radius else None,
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


def gt_for_case(ctx: StageContext, ingest: Any) -> tuple[Any, Path | None]:
    """The case's ground truth (or None) and its mesh path (or None)."""
    gt_dir = ctx.case.gt_dir or (str(ingest.gt_dir) if ingest.gt_dir else None)
    if not gt_dir:
        return None, None
    from endopipe.stages.io.ground_truth import open_ground_truth

    try:
        gt = open_ground_truth(gt_dir)
    except (ValueError, OSError):
        return None, None
    mesh_path = getattr(gt, "mesh_path", None)
    return gt, (mesh_path() if callable(mesh_path) else None)


def gt_poses_by_index(gt: Any, ingest: Any) -> dict[int, np.ndarray] | None:
    """GT c2w per endopipe frame index (via frames.json source_index), or None."""
    if gt is None or not gt.has_poses():
        return None
    poses = gt.poses()
    return {f.index: poses[f.source_index] for f in ingest.frames if f.source_index < len(poses)}


# --- the stage ----------------------------------------------------------------------------------
def _finite(v: Any) -> Any:
    """JSON has no inf / nan: such values become null (also inside lists and dicts)."""
    if isinstance(v, float) and not np.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_finite(x) for x in v]
    return v


def pick_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


class Mesh(Stage):
    """Surface of the lumen: TSDF fusion of the depth maps (or NeRF marching cubes), cleaned."""

    name = "mesh"
    needs = ("ingest", "poses", "centerline", "nerf", "depth")
    version = 1
    Config = MeshConfig

    @classmethod
    def view(cls, folder: Path) -> MeshView:
        return MeshView(folder)

    def run(self, ctx: StageContext) -> MeshSummary:
        cfg: MeshConfig = ctx.config  # type: ignore[assignment]
        ingest = ctx.input("ingest")
        poses: PosesView = ctx.input("poses")
        centerline = ctx.input("centerline")
        prior = centerline.prior()
        radius = float(prior.typical_radius)
        depth_dir = ctx.input_dir("depth")
        if not poses.registered:
            raise StageFailed("mesh: no registered frame in 02_poses")

        t0 = time.perf_counter()
        if cfg.method == "tsdf":
            raw, info = fuse_depth_folder(depth_dir, poses, cfg, radius, ingest.image)
        else:
            from endopipe.stages.nerf.render import load_model, surface_density_level

            trunc = cfg.depth_trunc or auto_depth_trunc(
                (d.depth for d in iter_depth_frames(depth_dir, poses, cfg.min_opacity)),
                cfg.depth_trunc_percentile,
            )
            device = pick_device(cfg.device)
            model = load_model(ctx.input_dir("nerf"), device)
            c2ws = [poses.c2w[i] for i in poses.registered]
            level = None
            if cfg.density_level is None:
                level = surface_density_level(model, prior, poses.intrinsics, c2ws)
            raw, info = density_mesh(
                nerf_density_fn(model), prior, c2ws, poses.intrinsics, cfg, trunc, device, level
            )
            info["frames_used"] = len(c2ws)
        build_s = time.perf_counter() - t0
        ctx.log(
            f"{cfg.method}: {len(raw.vertices)} vertices, {len(raw.faces)} faces "
            f"(voxel {info['voxel_size']:.3g}, depth_trunc {info['depth_trunc']:.3g}) "
            f"in {build_s:.1f} s"
        )
        if raw.empty:
            raise StageFailed(
                "mesh: the surface is empty"
                + (" (try another density_level)" if cfg.method == "marching_cubes" else "")
            )

        t1 = time.perf_counter()
        mesh, clean_info = clean_mesh(
            raw,
            min_component_fraction=cfg.min_component_fraction,
            min_component_diameter=cfg.min_component_diameter * radius,
            smooth_iterations=cfg.smooth_iterations,
            taubin_lambda=cfg.taubin_lambda,
            taubin_mu=cfg.taubin_mu,
        )
        clean_s = time.perf_counter() - t1
        write_mesh(ctx.out / "mesh.ply", mesh)
        if cfg.export_obj:
            write_mesh(ctx.out / "mesh.obj", mesh)

        metrics: dict[str, Any] = {"evaluated": False}
        if cfg.evaluate:
            gt, gt_mesh = gt_for_case(ctx, ingest)
            if gt_mesh is not None:
                truth = gt.centerline() if hasattr(gt, "centerline") else None
                fov = ingest.fov() if (ingest.folder / "fov_mask.png").is_file() else None
                metrics = evaluate_against_gt(
                    mesh,
                    poses,
                    gt_mesh,
                    gt_poses_by_index(gt, ingest),
                    info["depth_trunc"],
                    cfg,
                    gt_radius=float(np.mean(truth[1])) if truth is not None else None,
                    est_radius=float(np.mean(centerline.radius))
                    if centerline.kind == "tube"
                    else radius,
                    fov_mask=fov,
                )
                metrics["gt_kind"] = getattr(gt, "kind", "exact")
                if metrics.get("evaluated"):
                    ctx.log(
                        f"vs gt ({metrics['aligned']}): chamfer {metrics['chamfer']:.3f} "
                        f"({metrics['chamfer_pct_radius']:.2f}% of radius), F@"
                        f"{metrics['threshold']:.2g} {metrics['fscore']:.3f}"
                    )
            else:
                metrics["reason"] = "no ground-truth mesh"
        metrics.update(
            method=cfg.method,
            vertices=int(len(mesh.vertices)),
            faces=int(len(mesh.faces)),
            **{k: v if isinstance(v, int) else float(v) for k, v in info.items()},
            **clean_info,
        )
        metrics = {k: _finite(v) for k, v in metrics.items()}
        write_json(ctx.out / "metrics.json", metrics)
        keys = ("chamfer", "chamfer_pct_radius", "accuracy", "completeness", "fscore")
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
            evaluated=bool(metrics.get("evaluated")),
            threshold=metrics.get("threshold"),
            aligned=metrics.get("aligned"),
            **{k: metrics.get(k) for k in keys},
        )


class MeshView:
    """Typed access to 06_mesh: the mesh file(s) and the evaluation."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.mesh_path = self.folder / "mesh.ply"
        obj = self.folder / "mesh.obj"
        self.obj_path: Path | None = obj if obj.is_file() else None
        metrics = self.folder / "metrics.json"
        self.metrics: dict[str, Any] = json.loads(metrics.read_text()) if metrics.is_file() else {}

    @property
    def evaluated(self) -> bool:
        return bool(self.metrics.get("evaluated"))

    def load(self) -> RawMesh:
        return read_mesh(self.mesh_path)
