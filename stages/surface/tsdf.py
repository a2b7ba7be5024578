"""TSDF fusion of z-depth maps into a triangle mesh (open3d's tensor VoxelBlockGrid, CPU).

open3d 0.20's legacy ScalableTSDFVolume extracts empty meshes: not used. open3d integrates
with a pinhole matrix only: a distorted camera's maps are first resampled onto a pinhole grid
that covers its field of view (`PinholeResampler`), or, for a lens too wide for one (a wide
fisheye sees near 90 degrees off its axis, where a pinhole grid runs to infinity), onto the five
faces of a cube about the camera that look ahead of it, each a pinhole view of its own. A depth
is carried over as its ray's range, interpolated on a smooth wall and taken from the nearest
pixel across depth edges: never blended across an edge or into invalid (0) pixels.
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
            views = resamplers[key](fr)
        else:
            views = [(fr, k)]
        fused = sum(_integrate(vbg, v, c, depth_trunc, mult, colour) for v, c in views)
        used += int(fused > 0)
    if used == 0:
        return RawMesh.empty_mesh(), 0
    return _extract(vbg, colour, min_observations), used


def _integrate(
    vbg: Any, fr: DepthFrame, k: Camera, depth_trunc: float, mult: float, colour: bool
) -> int:
    """One pinhole view integrated into the grid: 1, or 0 when it touches no block."""
    import open3d as o3d
    import open3d.core as o3c

    h, w = fr.depth.shape
    if not ((fr.depth > 0) & (fr.depth < depth_trunc)).any():
        return 0
    K = o3c.Tensor(_open3d_matrix(k))
    w2c = o3c.Tensor(np.linalg.inv(np.asarray(fr.c2w, np.float64)))
    depth = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(fr.depth, np.float32)))
    try:
        blocks = vbg.compute_unique_block_coordinates(
            depth, K, w2c, 1.0, float(depth_trunc), trunc_voxel_multiplier=mult
        )
    except RuntimeError as e:  # a few scattered pixels can touch no block either
        if "No block is touched" in str(e):
            return 0
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
        vbg.integrate(blocks, depth, K, w2c, 1.0, float(depth_trunc), trunc_voxel_multiplier=mult)
    return 1


#: The most pixels one pinhole grid may have, in lens images: wider lenses go onto cube faces.
MAX_GRID_SHARE = 16
#: The widest ray fused, degrees off the axis (a pinhole face ends at 90).
MAX_RAY_DEG = 89.0
#: Ranges are interpolated between four valid lens pixels that differ from the nearest by at
#: most this share (a smooth wall); across a depth edge the nearest pixel's is taken.
EDGE_SHARE = 0.05


@dataclass
class PinholeView:
    """One pinhole grid a distorted camera's image is resampled onto: its camera, its rotation
    into the lens's camera frame, and where each of its pixels' rays lands in the lens's image.
    What is carried over is the range along the ray (the distance from the camera), not the
    z-depth (a neighbouring ray's z-depth is off by tan(angle) times the angle between the rays:
    1.5% at 60 degrees off the axis, half a pixel apart), interpolated on a smooth wall."""

    pinhole: Camera
    rotation: np.ndarray  # (3, 3): this view's camera frame -> the lens's
    map_u: np.ndarray  # (h, w) float32
    map_v: np.ndarray
    lens_range: np.ndarray  # (H, W) float32 on the lens's image: range per unit of z-depth
    z_scale: np.ndarray  # (h, w) float32 on this grid: z-depth per unit of range

    def __call__(self, frame: DepthFrame) -> DepthFrame:
        """The frame on this grid (nearest pixel); 0 where the lens's image has none."""
        import cv2

        def remap(img: np.ndarray, how: int = cv2.INTER_NEAREST) -> np.ndarray:
            return cv2.remap(img, self.map_u, self.map_v, how, borderMode=cv2.BORDER_CONSTANT)

        ranges = np.ascontiguousarray(frame.depth * self.lens_range, np.float32)
        nearest, linear = remap(ranges), remap(ranges, cv2.INTER_LINEAR)
        whole = remap((ranges > 0).astype(np.float32), cv2.INTER_LINEAR) > 0.999
        smooth = whole & (np.abs(linear - nearest) <= EDGE_SHARE * nearest)
        depth = np.where(smooth, linear, nearest) * self.z_scale
        rgb = remap(np.ascontiguousarray(frame.rgb)) if frame.rgb is not None else None
        c2w = np.asarray(frame.c2w, np.float64).copy()
        c2w[:3, :3] = c2w[:3, :3] @ self.rotation
        return DepthFrame(depth.astype(np.float32), c2w, rgb)


@dataclass
class PinholeResampler:
    """The pinhole views a distorted camera's image is fused through: one grid with the same
    focal lengths that covers every ray of it (a barrel lens sees further out than its own
    pinhole grid), or, when that grid would be too large, the cube faces ahead of the camera."""

    views: list[PinholeView]

    @classmethod
    def of(cls, camera: Camera) -> PinholeResampler:
        d = image_directions(camera)  # z = 1: the ideal ray of every pixel of the lens's image
        (x0, y0), (x1, y1) = d[..., :2].reshape(-1, 2).min(0), d[..., :2].reshape(-1, 2).max(0)
        w = int(np.ceil((x1 - x0) * camera.fx)) + 1
        h = int(np.ceil((y1 - y0) * camera.fy)) + 1
        if w * h <= MAX_GRID_SHARE * camera.width * camera.height:
            pinhole = Camera(
                width=w,
                height=h,
                fx=camera.fx,
                fy=camera.fy,
                cx=-x0 * camera.fx,
                cy=-y0 * camera.fy,
            )
            return cls([_view(camera, pinhole, np.eye(3))])
        views = [_face(camera, r) for r in _cube_rotations()]
        return cls([v for v in views if v is not None])

    @property
    def pinhole(self) -> Camera:
        """The one grid's camera (a lens on one grid)."""
        return self.views[0].pinhole

    def __call__(self, frame: DepthFrame) -> list[tuple[DepthFrame, Camera]]:
        return [(v(frame), v.pinhole) for v in self.views]


def _widest_cos(camera: Camera) -> float:
    """The cosine of the angle off the axis of the lens's widest ray (capped at MAX_RAY_DEG)."""
    d = image_directions(camera)
    widest = float(np.arctan(np.linalg.norm(d[..., :2], axis=-1).max()))
    return float(np.cos(min(widest, np.deg2rad(MAX_RAY_DEG))))


def _view(camera: Camera, pinhole: Camera, rotation: np.ndarray) -> PinholeView:
    """The lens's image seen through `pinhole` turned by `rotation`: nothing past its widest ray
    (a lens polynomial can fold back into the image there)."""
    rays = image_directions(pinhole) @ rotation.T  # in the lens's frame
    uv, _ = project_camera(camera, rays)
    unit_z = rays[..., 2] / np.linalg.norm(rays, axis=-1)
    uv[unit_z < _widest_cos(camera) - 1e-9] = -1e6
    mu, mv = (np.ascontiguousarray(uv[..., i], np.float32) for i in (0, 1))
    lens_range = np.linalg.norm(image_directions(camera), axis=-1).astype(np.float32)
    z_scale = 1.0 / np.linalg.norm(image_directions(pinhole), axis=-1)
    return PinholeView(pinhole, rotation, mu, mv, lens_range, z_scale.astype(np.float32))


def _cube_rotations() -> list[np.ndarray]:
    """Face-to-camera rotations of the cube faces that look ahead: forward, right, left, down,
    up (OpenCV axes: x right, y down, z forward)."""
    ahead = np.eye(3)
    right = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])  # face z = camera +x
    down = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # face z = camera +y
    return [ahead, right, right.T, down, down.T]


def _face(camera: Camera, rotation: np.ndarray) -> PinholeView | None:
    """A 90-degree pinhole face with the lens's central focal length, cropped to the pixels
    whose rays the lens sees; None when it sees none of them."""
    f = float(camera.fx)
    n = 2 * int(np.ceil(f)) + 1
    full = Camera(width=n, height=n, fx=f, fy=f, cx=(n - 1) / 2, cy=(n - 1) / 2)
    seen = _view(camera, full, rotation).map_u > -1e5
    inside = seen & (np.abs(image_directions(full)[..., :2]) <= 1.0).all(-1)
    if not inside.any():
        return None
    rows, cols = np.flatnonzero(inside.any(1)), np.flatnonzero(inside.any(0))
    crop = Camera(
        width=int(cols[-1] - cols[0] + 1),
        height=int(rows[-1] - rows[0] + 1),
        fx=f,
        fy=f,
        cx=full.cx - cols[0],
        cy=full.cy - rows[0],
    )
    return _view(camera, crop, rotation)


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
