"""TSDF fusion of z-depth maps into a triangle mesh (open3d's tensor VoxelBlockGrid, CPU).

open3d 0.20's legacy ScalableTSDFVolume extracts empty meshes: not used. open3d integrates
with a pinhole matrix only: a distorted camera's maps are first resampled onto a pinhole grid
that covers its field of view (`PinholeResampler`). A z-depth belongs to its ray, whatever the
grid; nearest-pixel resampling moves it by at most half a pixel of the lens's image and never
blends across depth edges or into invalid (0) pixels.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from endopipe.stages.camera import Camera, image_directions, project_camera
from endopipe.stages.surface.mesh import RawMesh


@dataclass
class DepthFrame:
    """One view to fuse: z-depth (H, W) float32 with 0 = invalid, its camera-to-world pose and
    optionally its colours (H, W, 3) uint8 on the same grid, and its own camera (windows of a
    recording may each have estimated theirs; None: the fusion's)."""

    depth: np.ndarray
    c2w: np.ndarray
    rgb: np.ndarray | None = None
    camera: Camera | None = None


def tsdf_fuse(
    frames: Iterable[DepthFrame],
    camera: Camera,
    voxel: float,
    sdf_trunc: float,
    depth_trunc: float,
    colour: bool = True,
    min_observations: int = 1,
    block_resolution: int = 16,
) -> tuple[RawMesh, int]:
    """The fused surface and the number of frames integrated. Depth maps may have another size
    than `camera` (the same camera scaled to them). A voxel needs `min_observations` frames to
    be part of the surface; depths beyond `depth_trunc` are ignored."""
    import open3d as o3d
    import open3d.core as o3c

    vbg = _voxel_grid(voxel, block_resolution, colour)
    mult = float(sdf_trunc) / float(voxel)
    used = 0
    resamplers: dict[str, PinholeResampler] = {}
    for fr in frames:
        if not ((fr.depth > 0) & (fr.depth < depth_trunc)).any():
            continue  # nothing to fuse (open3d raises on a frame that touches no block)
        h, w = fr.depth.shape
        own = fr.camera or camera
        k = own if (w, h) == (own.width, own.height) else own.scaled(w, h)
        if k.distorted:
            key = k.model_dump_json()
            if key not in resamplers:
                resamplers[key] = PinholeResampler.of(k)
            fr, k = resamplers[key](fr), resamplers[key].pinhole
            h, w = fr.depth.shape
        K = o3c.Tensor(_open3d_matrix(k))
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
    return _extract(vbg, colour, min_observations), used


@dataclass
class PinholeResampler:
    """Maps of a distorted camera's image onto a pinhole camera with the same focal lengths whose
    image covers every ray of it (a barrel lens sees further out than its own pinhole grid)."""

    pinhole: Camera
    map_u: np.ndarray  # (h, w) float32: where each pinhole pixel's ray lands in the lens's image
    map_v: np.ndarray

    @classmethod
    def of(cls, camera: Camera) -> PinholeResampler:
        d = image_directions(camera)  # z = 1: the ideal ray of every pixel of the lens's image
        (x0, y0), (x1, y1) = d[..., :2].reshape(-1, 2).min(0), d[..., :2].reshape(-1, 2).max(0)
        w = int(np.ceil((x1 - x0) * camera.fx)) + 1
        h = int(np.ceil((y1 - y0) * camera.fy)) + 1
        if w * h > 16 * camera.width * camera.height:
            raise ValueError(f"TSDF: the {camera.model} lens sees too wide for a pinhole grid")
        pinhole = Camera(
            width=w, height=h, fx=camera.fx, fy=camera.fy, cx=-x0 * camera.fx, cy=-y0 * camera.fy
        )
        rays = image_directions(pinhole)
        uv, _ = project_camera(camera, rays)
        # Past the image's widest ray a lens polynomial can fold back into the image: no data.
        r_max = np.linalg.norm(d[..., :2], axis=-1).max()
        uv[np.linalg.norm(rays[..., :2], axis=-1) > r_max] = -1e6
        mu, mv = (np.ascontiguousarray(uv[..., i], np.float32) for i in (0, 1))
        return cls(pinhole, mu, mv)

    def __call__(self, frame: DepthFrame) -> DepthFrame:
        """The frame on the pinhole grid (nearest pixel); 0 where the lens's image has none."""
        import cv2

        def remap(img: np.ndarray) -> np.ndarray:
            return cv2.remap(
                img, self.map_u, self.map_v, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT
            )

        depth = remap(np.ascontiguousarray(frame.depth, np.float32))
        rgb = remap(np.ascontiguousarray(frame.rgb)) if frame.rgb is not None else None
        return DepthFrame(depth, frame.c2w, rgb)


def _open3d_matrix(camera: Camera) -> np.ndarray:
    """The pinhole matrix in the convention open3d's integration reads: it looks a voxel's
    depth up at the integer part of its projection (pixel u covering [u, u+1)), where ours puts
    pixel u's centre at u (docs/formats.md); the principal point half a pixel on keeps each voxel
    on the pixel it projects into."""
    k = np.asarray(camera.matrix(), np.float64).copy()
    k[0, 2] += 0.5
    k[1, 2] += 0.5
    return k


def _voxel_grid(voxel: float, block_resolution: int, colour: bool) -> Any:
    """An empty open3d VoxelBlockGrid on the CPU with tsdf, weight (and colour) per voxel."""
    import open3d as o3d
    import open3d.core as o3c

    f32 = o3c.float32
    names, dtypes, channels = ["tsdf", "weight"], [f32, f32], [1, 1]
    if colour:
        names.append("color")
        dtypes.append(f32)
        channels.append(3)
    return o3d.t.geometry.VoxelBlockGrid(
        attr_names=tuple(names),
        attr_dtypes=tuple(dtypes),
        attr_channels=tuple(channels),
        voxel_size=float(voxel),
        block_resolution=int(block_resolution),
        block_count=1000,  # grows on demand
        device=o3c.Device("CPU:0"),
    )


def _extract(vbg: Any, colour: bool, min_observations: int) -> RawMesh:
    try:
        m = vbg.extract_triangle_mesh(weight_threshold=float(min_observations) - 0.5)
    except RuntimeError as e:  # open3d fails instead of returning an empty mesh
        if "has shape {0}" in str(e):
            return RawMesh.empty_mesh()
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
    return RawMesh(verts, faces, colours)
