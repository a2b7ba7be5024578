"""Points -> pixels for a `Camera`, with its lens distortion, and the lens model itself: written
once. (Pixels -> rays -> points is `rays.py`.)

`project` and `distort_normalised` take numpy arrays or torch tensors (the NeRF's L_geo warps
project on the training device).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import cv2
import numpy as np

from endopipe.stages.camera.model import Camera

Array = Any  # numpy array or torch tensor

#: OpenCV's iterative undistortion: at most this many iterations, or until the point it finds
#: re-distorts to within UNDISTORT_EPS (normalised units, ~1e-10 px at the focal lengths here).
UNDISTORT_ITER = 100
UNDISTORT_EPS = 1e-12


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
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, UNDISTORT_ITER, UNDISTORT_EPS)
    if camera.model == "fisheye":
        out = cv2.fisheye.undistortPoints(pts, eye, coeffs, criteria=criteria)
    else:
        out = cv2.undistortPoints(pts, eye, coeffs, criteria=criteria)
    out = out.reshape(xy_d.shape)
    missed = np.hypot(*np.moveaxis(distort_normalised(camera, out) - xy_d, -1, 0)) > 1e-9
    if missed.any() and (camera.model == "fisheye" or not any(camera.coefficients()[2:4])):
        out[missed] = _radial_inverse(camera, xy_d[missed])
    return out


def _radial_inverse(camera: Camera, xy_d: np.ndarray) -> np.ndarray:
    """A purely radial lens inverted along its radius, for the points OpenCV's fixed-point
    iteration does not bring back (it diverges where the barrel is strong: COLMAP's RADIAL
    estimate for C3VD, k1 -0.257 and k2 0.035 at 191 px, from 225 px out). A radius past the
    lens's peak has no ray and keeps the iteration's answer, which the caller can tell by
    re-distorting it."""
    image_r, ru = _radial_table(camera.model, tuple(float(c) for c in camera.dist or []))
    rd = np.hypot(xy_d[..., 0], xy_d[..., 1])
    r = np.interp(rd, image_r, ru, right=np.nan)
    scale = np.where(rd > 1e-12, r / np.maximum(rd, 1e-12), 1.0)
    out = xy_d * scale[..., None]
    reachable = np.isfinite(out).all(-1)
    return np.where(reachable[..., None], out, xy_d)


@lru_cache(maxsize=8)
def _radial_table(model: str, dist: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The lens's image radius against the ideal one, tabulated up to where it first stops
    growing (made once per lens: every frame's rays ask for it)."""
    lens = Camera(width=1, height=1, fx=1.0, fy=1.0, cx=0.0, cy=0.0, model=model, dist=list(dist))
    if model == "fisheye":
        ru = np.tan(np.linspace(0.0, np.pi / 2 - 1e-3, 200_001))
    else:
        ru = np.linspace(0.0, 20.0, 200_001)
    image_r = np.hypot(*np.moveaxis(distort_normalised(lens, np.stack([ru, 0 * ru], -1)), -1, 0))
    falls = np.nonzero(np.diff(image_r) <= 0)[0]
    end = int(falls[0]) + 1 if len(falls) else len(ru)
    return image_r[:end], ru[:end]


def project_camera(
    camera: Camera, points_cam: Array, near: float | None = None
) -> tuple[Array, Array]:
    """Camera-frame points (..., 3) -> (pixel coordinates (..., 2), z-depths (...)); numpy or
    torch. Points at z <= 0 get meaningless pixels: mask them with z. `near`: divide by
    max(z, near) instead (points behind the camera then land far outside the image)."""
    z = points_cam[..., 2]
    if near is not None:
        safe = np.maximum(z, near) if isinstance(z, np.ndarray) else z.clamp_min(near)
    elif isinstance(z, np.ndarray):
        safe = np.where(np.abs(z) < 1e-12, 1e-12, z)
    else:
        safe = z.where(z.abs() >= 1e-12, z.new_full((), 1e-12))
    x, y = points_cam[..., 0], points_cam[..., 1]
    if not camera.distorted:  # f x / z + c, in this order: the numbers endopipe always had
        return _stack([camera.fx * x / safe + camera.cx, camera.fy * y / safe + camera.cy]), z
    xy = distort_normalised(camera, _stack([x / safe, y / safe]))
    uv = _stack([camera.fx * xy[..., 0] + camera.cx, camera.fy * xy[..., 1] + camera.cy])
    return uv, z


def world_to_camera(points_world: Array, c2w: Array) -> Array:
    """World points (N, 3) into the frame of the camera at c2w: (4, 4), or one camera per point
    (N, 4, 4); numpy or torch."""
    if isinstance(points_world, np.ndarray):
        c2w = np.asarray(c2w, dtype=np.float64)
        if c2w.ndim == 3:
            return np.einsum("bji,bj->bi", c2w[:, :3, :3], points_world - c2w[:, :3, 3])
        w2c = np.linalg.inv(c2w)
        return points_world @ w2c[:3, :3].T + w2c[:3, 3]
    if c2w.dim() == 3:
        import torch

        return torch.einsum("bji,bj->bi", c2w[:, :3, :3], points_world - c2w[:, :3, 3])
    R, t = c2w[:3, :3], c2w[:3, 3]
    return (points_world - t) @ R


def project(
    camera: Camera, points_world: Array, c2w: Array, near: float | None = None
) -> tuple[Array, Array]:
    """World points (N, 3) -> (pixel coordinates (N, 2), z-depths (N,)) in the camera c2w
    ((4, 4) or (N, 4, 4)); see `project_camera` for `near`."""
    return project_camera(camera, world_to_camera(points_world, c2w), near)
