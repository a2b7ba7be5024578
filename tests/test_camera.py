"""The camera library against OpenCV and pycolmap: projection with each lens model, the ray
generator as its inverse, back-projection, resizing and cropping, rotations, the torch paths."""

from __future__ import annotations

import cv2
import numpy as np
import pycolmap
import pytest
import torch
from pydantic import ValidationError
from scipy.spatial.transform import Rotation

from endopipe.stages.camera import (
    Camera,
    backproject,
    camera_rays,
    direction_table,
    image_directions,
    lens_valid_mask,
    look_at,
    matrix_to_quat_wxyz,
    pixel_directions,
    pixel_grid,
    pixel_rays,
    project,
    project_camera,
    quat_wxyz_to_matrix,
)

W, H = 96, 72
BASE = {"width": W, "height": H, "fx": 70.0, "fy": 66.0, "cx": 47.3, "cy": 35.1}
#: Endoscope-like lenses: strong barrel distortion (k1 < 0), some tangential, a fisheye.
CAMERAS = {
    "pinhole": Camera(**BASE),
    "opencv5": Camera(**BASE, model="opencv", dist=[-0.32, 0.11, 0.0015, -0.0011, -0.015]),
    "opencv4": Camera(**BASE, model="opencv", dist=[-0.21, 0.04, -0.002, 0.001]),
    "fisheye": Camera(**BASE, model="fisheye", dist=[-0.04, 0.012, -0.003, 0.0005]),
}


def pose() -> np.ndarray:
    return look_at(np.array([1.0, -2.0, 0.5]), np.array([3.0, 1.0, 20.0]), np.array([0, -1.0, 0]))


def points_in_view(camera: Camera, n: int = 500, seed: int = 0) -> np.ndarray:
    """World points seen by `pose()` at 2-30 units, spread over the (ideal) field of view."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.6, 0.6, (n, 2))
    z = rng.uniform(2.0, 30.0, n)
    pc = np.column_stack([xy * z[:, None], z])
    c2w = pose()
    return pc @ c2w[:3, :3].T + c2w[:3, 3]


def opencv_project(camera: Camera, pts: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    w2c = np.linalg.inv(c2w)
    rvec, _ = cv2.Rodrigues(w2c[:3, :3])
    tvec = np.ascontiguousarray(w2c[:3, 3]).reshape(3, 1)
    if camera.model == "fisheye":
        out, _ = cv2.fisheye.projectPoints(
            pts.reshape(-1, 1, 3), rvec, tvec, camera.matrix(), camera.coefficients()
        )
    else:
        coeffs = camera.coefficients() if camera.distorted else np.zeros(5)
        out, _ = cv2.projectPoints(pts, rvec, tvec, camera.matrix(), coeffs)
    return out.reshape(-1, 2)


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_project_matches_opencv(name: str) -> None:
    camera = CAMERAS[name]
    pts = points_in_view(camera)
    uv, z = project(camera, pts, pose())
    assert np.abs(uv - opencv_project(camera, pts, pose())).max() < 1e-8
    pc = (pts - pose()[:3, 3]) @ pose()[:3, :3]
    assert np.allclose(z, pc[:, 2])


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_pixel_directions_invert_project_over_the_whole_image(name: str) -> None:
    """Every pixel centre (and sub-pixel positions) -> ray -> back onto the same pixel."""
    camera = CAMERAS[name]
    u, v = pixel_grid(W, H)
    u = np.concatenate([u.ravel(), np.linspace(-0.5, W - 0.5, 301)])
    v = np.concatenate([v.ravel(), np.linspace(H - 0.5, -0.5, 301)])
    d = pixel_directions(camera, u, v)
    assert np.allclose(d[:, 2], 1.0)
    uv, _ = project_camera(camera, d * 7.5)
    err = np.hypot(uv[:, 0] - u, uv[:, 1] - v)
    assert err.max() < 1e-6, err.max()
    if camera.distorted:  # the lens moves rays: the inverse is not the pinhole one
        ideal = pixel_directions(camera.pinhole(), u, v)
        assert np.abs(d - ideal).max() > 1e-3


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_every_pixel_of_a_lens_that_reaches_the_image_has_a_ray(name: str) -> None:
    assert lens_valid_mask(CAMERAS[name]).all()


def test_a_lens_that_bends_back_gives_no_ray_beyond_its_reach() -> None:
    """C3VD's estimate: SIMPLE_RADIAL (OpenCV k1 alone) with k1 = -0.12 at f = 156 px. Its image
    radius f r (1 + k1 r^2) peaks at r = 1 / sqrt(3 |k1|): 175 px. Pixels inside keep their
    ray; beyond, no direction reaches them, and none is made up."""
    k1, f = -0.12, 156.0
    cam = Camera(
        width=400, height=400, fx=f, fy=f, cx=199.5, cy=199.5, model="opencv", dist=[k1, 0, 0, 0]
    )
    reach = f / np.sqrt(3 * abs(k1)) * (2 / 3)
    ok = lens_valid_mask(cam)
    u, v = pixel_grid(400, 400)
    r = np.hypot(u - 199.5, v - 199.5)
    assert ok[r < reach - 2].all() and not ok[r > reach + 2].any()
    # With k2 > 0 (COLMAP's RADIAL on the same footage: -0.257, 0.035 at 191 px) it reaches all.
    wide = cam.model_copy(update={"fx": 191.0, "fy": 191.0, "dist": [-0.257, 0.035, 0, 0]})
    assert lens_valid_mask(wide).all()


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_backproject_then_project_is_the_pixel_grid(name: str) -> None:
    camera = CAMERAS[name]
    rng = np.random.default_rng(1)
    depth = rng.uniform(1.0, 40.0, (H, W))
    pts = backproject(camera, depth, pose())
    uv, z = project(camera, pts.reshape(-1, 3), pose())
    u, v = pixel_grid(W, H)
    assert np.abs(uv - np.column_stack([u.ravel(), v.ravel()])).max() < 1e-6
    assert np.allclose(z, depth.ravel(), rtol=1e-12)  # z-depth, not ray length
    o, d = camera_rays(camera, pose())
    assert np.allclose(o + depth.reshape(-1, 1) * d, pts.reshape(-1, 3))
    # a depth map of another size is the same camera scaled to it
    small = backproject(camera, depth[::2, ::2], pose())
    uv2, _ = project(camera.scaled(W // 2, H // 2), small.reshape(-1, 3), pose())
    u2, v2 = pixel_grid(W // 2, H // 2)
    assert np.abs(uv2 - np.column_stack([u2.ravel(), v2.ravel()])).max() < 1e-6


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_scaled_and_cropped_see_the_same_points(name: str) -> None:
    """A scaled camera puts a point where the resized image has it (pixel-centre convention:
    u' = (u + 0.5) s - 0.5); a crop shifts pixels by its corner."""
    camera = CAMERAS[name]
    pts = points_in_view(camera, seed=2)
    uv, _ = project(camera, pts, pose())
    big = camera.scaled(2 * W, 3 * H)
    uv_big, _ = project(big, pts, pose())
    assert np.allclose(uv_big, (uv + 0.5) * [2.0, 3.0] - 0.5, atol=1e-9)
    assert (big.width, big.height, big.model, big.dist) == (2 * W, 3 * H, camera.model, camera.dist)
    crop = camera.cropped(10, 7, 50, 40)
    uv_crop, _ = project(crop, pts, pose())
    assert np.allclose(uv_crop, uv - [10.0, 7.0], atol=1e-9)
    assert (crop.width, crop.height) == (50, 40)
    # OpenCV agrees on the scaled camera's image of a pixel-corner-aligned resize
    assert np.abs(uv_big - opencv_project(big, pts, pose())).max() < 1e-8


def test_camera_validates_its_lens() -> None:
    assert Camera(**BASE, dist=[-0.1, 0.01, 0, 0, 0]).model == "opencv"  # intrinsics.json form
    assert not Camera(**BASE, model="opencv", dist=[0, 0, 0, 0]).distorted
    with pytest.raises(ValidationError):
        Camera(**BASE, model="pinhole", dist=[0.1, 0, 0, 0])
    with pytest.raises(ValidationError):
        Camera(**BASE, model="fisheye", dist=[0.1, 0, 0, 0, 0])
    with pytest.raises(ValidationError):
        Camera(**{**BASE, "fx": 0.0})


def test_quaternions_agree_with_pycolmap_and_scipy() -> None:
    rots = Rotation.random(50, random_state=3)
    for R in rots.as_matrix():
        q = matrix_to_quat_wxyz(R)
        assert q[0] >= 0 and np.isclose(np.linalg.norm(q), 1.0)
        colmap = pycolmap.Rotation3d(np.array([q[1], q[2], q[3], q[0]]))  # xyzw
        assert np.allclose(colmap.matrix(), R, atol=1e-12)
        assert np.allclose(quat_wxyz_to_matrix(q), R, atol=1e-12)
        assert np.allclose(quat_wxyz_to_matrix(-q), R, atol=1e-12)  # q and -q: one rotation
    # COLMAP's images.txt order (w, x, y, z): 90 degrees about z
    assert np.allclose(
        quat_wxyz_to_matrix([np.sqrt(0.5), 0, 0, np.sqrt(0.5)]),
        [[0, -1, 0], [1, 0, 0], [0, 0, 1]],
        atol=1e-12,
    )


# --- torch -----------------------------------------------------------------------------------


def test_torch_pinhole_rays_are_the_nerfs_formula_bit_for_bit() -> None:
    """The NeRF trained with these exact float32 operations; the library must not change them."""
    camera = CAMERAS["pinhole"]
    g = torch.Generator().manual_seed(0)
    u = torch.randint(0, W, (777,), generator=g).float()
    v = torch.rand(777, generator=g) * (H - 1)
    c2w = torch.as_tensor(pose(), dtype=torch.float32)
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    dc = torch.stack([(u - cx) / fx, (v - cy) / fy, torch.ones_like(u)], -1)
    o, d = pixel_rays(camera, c2w, u, v)
    assert torch.equal(d, dc @ c2w[:3, :3].T) and torch.equal(o, c2w[:3, 3].expand_as(d))
    batch = c2w.expand(777, 4, 4)
    o_b, d_b = pixel_rays(camera, batch, u, v)
    assert torch.equal(d_b, torch.einsum("bij,bj->bi", batch[:, :3, :3], dc))
    assert torch.equal(o_b, batch[:, :3, 3])
    assert direction_table(camera) is None


@pytest.mark.parametrize("name", ["opencv5", "fisheye"])
def test_torch_distorted_rays_match_numpy_and_the_table(name: str) -> None:
    camera = CAMERAS[name]
    table = direction_table(camera)
    assert table.shape == (H, W, 3)
    assert np.allclose(table.numpy(), image_directions(camera), atol=1e-6)
    g = torch.Generator().manual_seed(1)
    u = torch.randint(0, W, (300,), generator=g).float()  # pixel centres, as training draws
    v = torch.randint(0, H, (300,), generator=g).float()
    exact = pixel_directions(camera, u.double().numpy(), v.double().numpy())
    from_table = pixel_directions(camera, u, v, table)
    assert from_table.dtype == torch.float32
    assert np.allclose(from_table.numpy(), exact, atol=1e-6)
    # off the pixel centres the table is not used: still exact
    uf, vf = u + 0.37, v * 0.5 + 0.21
    off = pixel_directions(camera, uf, vf, table)
    want = pixel_directions(camera, uf.double().numpy(), vf.double().numpy())
    assert np.allclose(off.numpy(), want, atol=1e-6)


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_torch_project_matches_numpy(name: str) -> None:
    camera = CAMERAS[name]
    pts = points_in_view(camera, seed=4)
    uv, z = project(camera, pts, pose())
    uv_t, z_t = project(
        camera, torch.as_tensor(pts), torch.as_tensor(pose()).expand(len(pts), 4, 4)
    )
    assert np.allclose(uv_t.numpy(), uv, atol=1e-9) and np.allclose(z_t.numpy(), z)
    uv_1, _ = project(camera, torch.as_tensor(pts), torch.as_tensor(pose()))
    assert np.allclose(uv_1.numpy(), uv, atol=1e-9)


def test_near_clamp_keeps_points_behind_the_camera_out_of_the_image() -> None:
    camera = CAMERAS["pinhole"]
    behind = np.array([[0.5, 0.2, -3.0], [0.01, 0.0, 1e-9]])
    uv, z = project_camera(camera, behind, near=1e-4)
    assert z[0] == -3.0 and (np.abs(uv - [camera.cx, camera.cy]) > W).any(axis=1).all()


def test_a_fisheye_with_zero_coefficients_is_equidistant() -> None:
    """OpenCV's and COLMAP's fisheye with k = 0 puts a ray theta off the axis at f theta, not at
    f tan(theta): the camera must not take it for a pinhole."""
    from endopipe.stages.camera import Camera
    from endopipe.stages.camera.projection import project_camera

    cam = Camera(
        width=320,
        height=256,
        fx=160,
        fy=160,
        cx=159.5,
        cy=127.5,
        model="fisheye",
        dist=[0, 0, 0, 0],
    )
    theta = np.radians(50.0)
    uv, _ = project_camera(cam, np.array([[np.sin(theta), 0.0, np.cos(theta)]]))
    assert abs(uv[0, 0] - (159.5 + 160 * theta)) < 1e-6
