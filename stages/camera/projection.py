"""Pixels <-> rays <-> points for a `Camera`, with its lens distortion: written once.

Every function takes numpy arrays, and `project` / `distort_normalised` take torch tensors too
(the NeRF's L_geo warps project on the training device). A ray's direction is returned with
camera-frame z = 1, so a ray parameter is a z-depth (DESIGN §4).
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from endopipe.stages.camera.model import Camera

Array = Any  # numpy array or torch tensor


def _stack(parts: list[Array], axis: int = -1) -> Array:
    if isinstance(parts[0], np.ndarray):
        return np.stack(parts, axis)
    import torch

    return torch.stack(parts, axis)


def _sqrt(x: Array) -> Array:
    return np.sqrt(x) if isinstance(x, np.ndarray) else x.sqrt()


def _atan(x: Array) -> Array:
    return np.arctan(x) if isinstance(x, np.ndarray) else x.atan()


def pixel_grid(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates (u, v) as two HxW float arrays."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    return u, v


def distort_normalised(camera: Camera, xy: Array) -> Array:
    """Ideal normalised coordinates (x/z, y/z), (..., 2) -> where the lens puts them."""
    if not camera.distorted:
        return xy
    d = [float(c) for c in camera.dist or []]
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    if camera.model == "fisheye":
        r = _sqrt(r2)
        theta = _atan(r)
        t2 = theta * theta
        theta_d = theta * (1 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3]))))
        scale = theta_d / r.clamp_min(1e-12) if not isinstance(r, np.ndarray) else None
        if scale is None:
            scale = np.where(r > 1e-12, theta_d / np.maximum(r, 1e-12), 1.0)
        else:
            scale = scale.where(r > 1e-12, scale.new_ones(()))
        return _stack([x * scale, y * scale])
    k1, k2, p1, p2 = d[:4]
    k3 = d[4] if len(d) > 4 else 0.0
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return _stack([xd, yd])


def undistort_normalised(camera: Camera, xy_d: np.ndarray) -> np.ndarray:
    """Where the lens put a point (distorted normalised coordinates, (..., 2)) -> its ideal
    normalised coordinates; OpenCV's iterative inversion."""
    xy_d = np.asarray(xy_d, dtype=np.float64)
    if not camera.distorted:
        return xy_d
    pts = xy_d.reshape(-1, 1, 2)
    eye, coeffs = np.eye(3), camera.coefficients()
    if camera.model == "fisheye":
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
        out = cv2.fisheye.undistortPoints(pts, eye, coeffs, criteria=criteria)
    else:
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
        out = cv2.undistortPointsIter(pts, eye, coeffs, None, None, criteria)
    return out.reshape(xy_d.shape)


def pixel_directions(camera: Camera, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Camera-frame ray directions (..., 3) with z = 1 through pixel coordinates (u, v)."""
    u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
    xy = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy], -1)
    xy = undistort_normalised(camera, xy)
    return np.concatenate([xy, np.ones_like(xy[..., :1])], -1)


def image_directions(camera: Camera) -> np.ndarray:
    """Camera-frame directions (H, W, 3), z = 1, through every pixel centre of the image."""
    return pixel_directions(camera, *pixel_grid(camera.width, camera.height))


def camera_rays(camera: Camera, c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-frame rays through every pixel: origins and directions (H*W, 3), direction z = 1 in
    the camera frame (a ray parameter is a z-depth)."""
    d = image_directions(camera).reshape(-1, 3) @ np.asarray(c2w)[:3, :3].T
    o = np.broadcast_to(np.asarray(c2w)[:3, 3], d.shape)
    return o, d


def project_camera(camera: Camera, points_cam: Array) -> tuple[Array, Array]:
    """Camera-frame points (N, 3) -> (pixel coordinates (N, 2), z-depths (N,)); numpy or torch.
    Points at z <= 0 get meaningless pixels: mask them with z."""
    z = points_cam[..., 2]
    if isinstance(z, np.ndarray):
        safe = np.where(np.abs(z) < 1e-12, 1e-12, z)
    else:
        safe = z.where(z.abs() >= 1e-12, z.new_full((), 1e-12))
    xy = distort_normalised(camera, _stack([points_cam[..., 0] / safe, points_cam[..., 1] / safe]))
    uv = _stack([camera.fx * xy[..., 0] + camera.cx, camera.fy * xy[..., 1] + camera.cy])
    return uv, z


def world_to_camera(points_world: Array, c2w: Array) -> Array:
    """World points (N, 3) into the frame of the camera at c2w (numpy or torch)."""
    if isinstance(points_world, np.ndarray):
        w2c = np.linalg.inv(np.asarray(c2w, dtype=np.float64))
        return points_world @ w2c[:3, :3].T + w2c[:3, 3]
    R, t = c2w[:3, :3], c2w[:3, 3]
    return (points_world - t) @ R


def project(camera: Camera, points_world: Array, c2w: Array) -> tuple[Array, Array]:
    """World points (N, 3) -> (pixel coordinates (N, 2), z-depths (N,)) in the camera c2w."""
    return project_camera(camera, world_to_camera(points_world, c2w))


def backproject(camera: Camera, depth: np.ndarray, c2w: np.ndarray | None = None) -> np.ndarray:
    """HxW z-depth -> HxWx3 points (camera frame, or world frame when c2w is given)."""
    if depth.shape != (camera.height, camera.width):
        camera = camera.scaled(depth.shape[1], depth.shape[0])
    pts = image_directions(camera) * depth[..., None]
    if c2w is not None:
        pts = pts @ np.asarray(c2w)[:3, :3].T + np.asarray(c2w)[:3, 3]
    return pts
