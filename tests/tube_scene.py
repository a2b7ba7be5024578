"""A tiny analytic scene for the NeRF tests: a straight textured tube closed by an end wall, lit
by a light at the camera, 40 x 32 pixels, rendered exactly, so the tests need neither the synth
generator nor COLMAP; and the small config that trains on it in seconds."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from endopipe.stages.camera import Camera, look_at
from endopipe.stages.centerline.prior import TubePrior
from endopipe.stages.nerf.config import NerfConfig
from endopipe.stages.nerf.data import FrameSet, holdout_split
from endopipe.stages.nerf.stage import fit_box

RADIUS = 10.0
END_Z = 60.0
W, H = 40, 32


def tube_frame(k: Camera, c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact render of the tube x^2 + y^2 = R^2 closed at z = END_Z: sRGB image, z-depth."""
    u, v = np.meshgrid(np.arange(k.width, dtype=float), np.arange(k.height, dtype=float))
    dc = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)], -1)
    d = dc @ c2w[:3, :3].T
    o = c2w[:3, 3]
    a = d[..., 0] ** 2 + d[..., 1] ** 2
    b = 2 * (o[0] * d[..., 0] + o[1] * d[..., 1])
    c = o[0] ** 2 + o[1] ** 2 - RADIUS**2
    t_cyl = (-b + np.sqrt(np.maximum(b * b - 4 * a * c, 0))) / np.maximum(2 * a, 1e-12)
    t_cyl = np.where(a > 1e-12, t_cyl, np.inf)
    t_end = np.where(d[..., 2] > 1e-9, (END_Z - o[2]) / np.maximum(d[..., 2], 1e-9), np.inf)
    t = np.minimum(t_cyl, t_end)
    p = o + t[..., None] * d
    normal = np.where(
        (t_cyl < t_end)[..., None],
        -np.stack([p[..., 0], p[..., 1], np.zeros_like(t)], -1) / RADIUS,
        np.array([0.0, 0.0, -1.0]),
    )
    theta = np.arctan2(p[..., 1], p[..., 0])
    albedo = 0.55 + 0.3 * np.sin(5 * theta)[..., None] * np.sin(0.7 * p[..., 2])[..., None] * [
        1.0,
        0.6,
        0.5,
    ]
    albedo = albedo + 0.15 * np.sin(0.5 * p[..., 0] + 0.3 * p[..., 2])[..., None]
    r = t * np.linalg.norm(d, axis=-1)
    cos = np.clip(-(normal * d).sum(-1) / np.linalg.norm(d, axis=-1), 0, 1)
    lin = np.clip(albedo * (60.0 * cos / r**2 + 0.02)[..., None], 0, 1)
    rgb = (lin ** (1 / 2.2) * 255).round().astype(np.uint8)
    depth = (t * dc[..., 2]).astype(np.float32)  # dc z = 1: t is the z-depth
    return rgb, depth


def tube_poses(n: int) -> list[np.ndarray]:
    poses = []
    for i in range(n):
        z = 2.0 + 1.2 * i
        eye = np.array([0.8 * np.sin(0.4 * i), 0.6 * np.cos(0.3 * i), z])
        poses.append(look_at(eye, np.array([0.0, 0.0, z + 30.0]), np.array([0.0, -1.0, 0.0])))
    return poses


def intrinsics() -> Camera:
    f = 0.5 * W / np.tan(np.radians(45))
    return Camera(width=W, height=H, fx=f, fy=f, cx=(W - 1) / 2, cy=(H - 1) / 2)


def tube_prior() -> TubePrior:
    z = np.linspace(-5.0, END_Z + 5, 30)
    return TubePrior(np.stack([np.zeros_like(z), np.zeros_like(z), z], 1), RADIUS)


def tiny_config(**train) -> NerfConfig:
    cfg = NerfConfig()
    cfg.field.tensorf.res_init = 24
    cfg.field.tensorf.res_final = 40
    cfg.sampling.n_coarse = 32
    cfg.sampling.n_fine = 16
    cfg.sampling.n_uniform = 4
    cfg.train.batch_rays = 256
    cfg.train.steps = 80
    cfg.train.checkpoint_every = 20
    cfg.train.time_budget_s = None  # step-based: deterministic, so resume can match exactly
    for k, v in train.items():
        setattr(cfg.train, k, v)
    return cfg


def tiny_setup(cfg: NerfConfig, n_frames: int = 10, device: str = "cpu"):
    k = intrinsics()
    poses = tube_poses(n_frames)
    renders = [tube_frame(k, p) for p in poses]
    images = np.stack([r[0] for r in renders]).astype(np.float32) / 255.0
    masks = np.ones(images.shape[:3], bool)
    prior = tube_prior()
    box = fit_box(poses, k, (H, W), prior, cfg)
    c2w_s = np.stack([box.c2w_to_scene(p) for p in poses])
    ids = list(range(n_frames))
    frames = FrameSet(images, masks, c2w_s, k, ids, torch.device(device))
    train, held = holdout_split(ids, cfg.train.holdout_every)
    return frames, train, held, prior, box, k, poses, [r[1] for r in renders]


@pytest.fixture
def one_torch_thread():
    """The tests train with one torch thread: the same on every machine, and no contention."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
