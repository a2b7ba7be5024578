"""The one ray generator: pixels -> camera-frame directions -> world rays, numpy or torch.

A direction is returned with camera-frame z = 1, so a ray parameter is a z-depth (docs/formats.md).
For a pinhole camera the torch path computes directions on the tensors' device, in the same
operations as the NeRF always did (bit-for-bit the numbers it trained with). A distorted lens has
no closed-form inverse: its directions come from OpenCV's iterative undistortion (on the CPU,
without gradients to the pixel coordinates), and training, which draws pixel centres thousands
of times per step, looks them up in a per-pixel table made once (`direction_table`).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np

from endopipe.stages.camera.model import Camera
from endopipe.stages.camera.projection import pixel_grid, undistort_normalised

Array = Any  # numpy array or torch tensor


def _pinhole_torch(camera: Camera, u: Array, v: Array) -> Array:
    import torch

    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    return torch.stack([(u - cx) / fx, (v - cy) / fy, torch.ones_like(u)], -1)


def _is_pixel_centres(table: Array, u: Array, v: Array) -> bool:
    h, w = table.shape[:2]
    return bool(
        (u == u.round()).all()
        and (v == v.round()).all()
        and (u >= 0).all()
        and (u <= w - 1).all()
        and (v >= 0).all()
        and (v <= h - 1).all()
    )


def pixel_directions(camera: Camera, u: Array, v: Array, table: Array | None = None) -> Array:
    """Camera-frame ray directions (..., 3) with z = 1 through pixel coordinates (u, v), with the
    lens distortion undone; numpy (float64) or torch (u's dtype and device). `table`, from
    `direction_table`, answers pixel centres of a distorted camera without OpenCV."""
    if isinstance(u, np.ndarray) or np.isscalar(u):
        u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
        xy = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy], -1)
        xy = undistort_normalised(camera, xy)
        return np.concatenate([xy, np.ones_like(xy[..., :1])], -1)
    if not camera.distorted:
        return _pinhole_torch(camera, u, v)
    import torch

    if table is not None and _is_pixel_centres(table, u, v):
        return table[v.long(), u.long()].to(u.dtype)
    uv = [t.detach().cpu().double().numpy() for t in (u, v)]
    return torch.as_tensor(pixel_directions(camera, *uv), dtype=u.dtype, device=u.device)


def direction_table(camera: Camera, device: Any = None) -> Any:
    """Directions (H, W, 3) of every pixel centre as a float32 torch tensor on `device` for a
    distorted camera, None for a pinhole (its directions are cheaper to compute than to look
    up)."""
    if not camera.distorted:
        return None
    import torch

    return torch.tensor(image_directions(camera), dtype=torch.float32, device=device)


#: A pixel whose undone ray, put back through the lens, lands further than this from it has no
#: ray: the lens model does not reach it (below).
LENS_ROUND_TRIP_PX = 0.5


def lens_valid_mask(camera: Camera) -> np.ndarray:
    """(H, W) bool: the pixels the lens model gives a ray. A polynomial lens bends back at some
    radius (SIMPLE_RADIAL with k1 < 0 at r = 1 / sqrt(3 |k1|) focal lengths), and beyond it no
    direction maps to the pixel: its "undistortion" is a wrong ray. C3VD's estimated k1 = -0.12
    stops 173 px from the centre, 5% of the scope's field of view; those rays pointed up to 52 px
    off. A pinhole reaches every pixel."""
    if not camera.distorted:
        return np.ones((camera.height, camera.width), dtype=bool)
    from endopipe.stages.camera.projection import project_camera

    u, v = pixel_grid(camera.width, camera.height)
    dirs = image_directions(camera)
    uv, _ = project_camera(camera, dirs)
    err = np.hypot(uv[..., 0] - u, uv[..., 1] - v)
    return np.isfinite(err) & (err <= LENS_ROUND_TRIP_PX)


def image_directions(camera: Camera) -> np.ndarray:
    """Camera-frame directions (H, W, 3), z = 1, through every pixel centre of the image; read
    only, and computed once per camera (a distorted lens costs an iterative undistortion of
    every pixel: 86 ms for a 319x320 image, more than ray casting the whole image)."""
    return _image_directions(camera.model_dump_json())


@lru_cache(maxsize=8)
def _image_directions(camera_json: str) -> np.ndarray:
    camera = Camera.model_validate_json(camera_json)
    dirs = pixel_directions(camera, *pixel_grid(camera.width, camera.height))
    dirs.setflags(write=False)
    return dirs


def rays_from_directions(c2w: Array, dirs: Array) -> tuple[Array, Array]:
    """Camera-frame directions (B, 3) -> world origins and directions (B, 3); c2w (4, 4) or one
    per ray (B, 4, 4); numpy or torch (directions cast to c2w's dtype)."""
    if isinstance(c2w, np.ndarray):
        c2w = np.asarray(c2w, dtype=np.float64)
        if c2w.ndim == 2:
            d = dirs @ c2w[:3, :3].T
            return np.broadcast_to(c2w[:3, 3], d.shape), d
        return c2w[:, :3, 3], np.einsum("bij,bj->bi", c2w[:, :3, :3], dirs)
    import torch

    dirs = dirs.to(c2w.dtype)
    if c2w.dim() == 2:
        d = dirs @ c2w[:3, :3].T
        o = c2w[:3, 3].expand_as(d)
    else:
        d = torch.einsum("bij,bj->bi", c2w[:, :3, :3], dirs)
        o = c2w[:, :3, 3]
    return o.contiguous(), d.contiguous()


def pixel_rays(
    camera: Camera, c2w: Array, u: Array, v: Array, table: Array | None = None
) -> tuple[Array, Array]:
    """World rays through pixel coordinates (u, v) of the camera at c2w ((4, 4) or (B, 4, 4)):
    origins and directions (B, 3), direction z = 1 in the camera frame; numpy or torch."""
    return rays_from_directions(c2w, pixel_directions(camera, u, v, table))


def camera_rays(camera: Camera, c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-frame rays through every pixel centre, row-major: origins and directions (H*W, 3),
    direction z = 1 in the camera frame (a ray parameter is a z-depth)."""
    d = image_directions(camera).reshape(-1, 3) @ np.asarray(c2w)[:3, :3].T
    o = np.broadcast_to(np.asarray(c2w)[:3, 3], d.shape)
    return o, d


def backproject(camera: Camera, depth: np.ndarray, c2w: np.ndarray | None = None) -> np.ndarray:
    """HxW z-depth -> HxWx3 points (camera frame, or world frame when c2w is given); a depth
    map of another size than the camera's is taken as the same camera scaled to it."""
    if depth.shape != (camera.height, camera.width):
        camera = camera.scaled(depth.shape[1], depth.shape[0])
    pts = image_directions(camera) * depth[..., None]
    if c2w is not None:
        pts = pts @ np.asarray(c2w)[:3, :3].T + np.asarray(c2w)[:3, 3]
    return pts
