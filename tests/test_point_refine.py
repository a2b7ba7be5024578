"""The SfM points' multi-view refinement: points pushed off a textured wall along their rays come
back to it; a point on a flat wall (nothing to correlate) stays where it was."""

from __future__ import annotations

import numpy as np

from endopipe.stages.camera.model import Camera
from endopipe.stages.camera.rays import pixel_directions
from endopipe.stages.nerf.point_refine import refine_points
from endopipe.stages.poses.view import SparseObservations

CAMERA = Camera(width=128, height=96, fx=100.0, fy=100.0, cx=63.5, cy=47.5)
WALL_Z = 10.0


def texture(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    rng = np.random.default_rng(3)
    out = np.zeros_like(x)
    for _ in range(8):
        fx, fy = rng.uniform(-3, 3, 2)
        out += np.sin(fx * x + fy * y + rng.uniform(0, 6.3))
    return 0.5 + 0.06 * out


def cameras(n: int) -> dict[int, np.ndarray]:
    """A camera sliding sideways in front of the wall z = WALL_Z, looking at it."""
    out = {}
    for i in range(n):
        c2w = np.eye(4)
        c2w[:3, 3] = [0.15 * i, 0.02 * i, 0.0]
        out[i] = c2w
    return out


def render(c2w: np.ndarray, flat: bool = False) -> np.ndarray:
    v, u = np.mgrid[0 : CAMERA.height, 0 : CAMERA.width].astype(np.float64)
    d = pixel_directions(CAMERA, u.ravel(), v.ravel()) @ c2w[:3, :3].T
    t = (WALL_Z - c2w[2, 3]) / d[:, 2]
    hit = c2w[:3, 3] + t[:, None] * d
    grey = np.full(len(hit), 0.5) if flat else texture(hit[:, 0], hit[:, 1])
    return grey.reshape(CAMERA.height, CAMERA.width)


def observations(
    c2w: dict[int, np.ndarray], errors: np.ndarray
) -> tuple[SparseObservations, np.ndarray]:
    """Points on the wall seen by every camera, each pushed along the middle camera's ray by
    its relative error; (observations, the true points)."""
    rng = np.random.default_rng(0)
    n = len(errors)
    truth = np.column_stack(
        [rng.uniform(-1.5, 2.5, n), rng.uniform(-1.2, 1.5, n), np.full(n, WALL_Z)]
    )
    ref = c2w[len(c2w) // 2][:3, 3]
    noisy = ref + (truth - ref) * (1.0 + errors[:, None])
    frames = np.repeat(np.array(sorted(c2w)), n)
    xyz = np.tile(noisy, (len(c2w), 1))
    uv = np.zeros((len(xyz), 2))
    k = len(xyz)
    obs = SparseObservations(
        frames, uv, xyz, np.full(k, len(c2w)), np.full(k, 0.5), np.full(k, 5.0)
    )
    return obs, truth


def depth_error(points: np.ndarray, truth: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    return np.abs(points[:, 2] - c2w[2, 3]) / (truth[:, 2] - c2w[2, 3]) - 1.0


def test_points_pushed_off_a_textured_wall_come_back_to_it() -> None:
    c2w = cameras(9)
    errors = np.random.default_rng(1).uniform(-0.08, 0.08, 40)
    obs, truth = observations(c2w, errors)
    images = {i: render(m) for i, m in c2w.items()}
    refined, moved = refine_points(obs, CAMERA, c2w, images)
    assert moved.mean() > 0.8
    ref = c2w[4]
    first = refined.xyz[: len(truth)]
    before = np.abs(depth_error(obs.xyz[: len(truth)], truth, ref))
    after = np.abs(depth_error(first, truth, ref))
    # 8% at most before; within half a percent after (the sub-step parabola)
    assert np.median(before) > 0.03
    assert np.median(after) < 0.005, np.median(after)
    # the observations' pixels are the refined points' projections
    projected = 63.5 + 100 * (first[:, 0] - c2w[0][0, 3]) / first[:, 2]
    assert np.allclose(refined.uv[: len(truth), 0], projected, atol=1e-6)


def test_a_point_on_a_flat_wall_stays() -> None:
    c2w = cameras(5)
    obs, _ = observations(c2w, np.array([0.05, -0.05]))
    images = {i: render(m, flat=True) for i, m in c2w.items()}
    refined, moved = refine_points(obs, CAMERA, c2w, images)
    assert not moved.any()
    assert np.array_equal(refined.xyz, obs.xyz)


def test_the_patch_through_a_fisheye_lies_where_its_nine_probes_put_it() -> None:
    """The correlation projects nine pixels a patch and places the rest by the quadratic through
    them: through C3VD's own fisheye, between two views of a plane, the other pixels lie within
    a thousandth of a pixel of their own projections (3e-5 px measured; an affine map of the
    centre and its axes' ends puts them 0.012-0.016 px off here, 0.35 px at worst on C3VD)."""
    from endopipe.stages.camera.projection import project_camera, world_to_camera
    from endopipe.stages.nerf.point_refine import HALF, _probes

    fisheye = Camera(
        width=320, height=320, fx=148.0, fy=148.0, cx=159.0, cy=159.5, model="fisheye",
        dist=[0.1127, 0.0013, -0.0045, 0.0003],
    )  # fmt: skip
    grid = np.arange(-HALF, HALF + 1, dtype=np.float64)
    offsets = np.stack(np.meshgrid(grid, grid), -1).reshape(-1, 2)
    probes, weights = _probes(offsets)
    other = np.eye(4)
    other[:3, 3] = [0.3, -0.1, 0.2]
    angle = np.radians(12)
    other[:3, :3] = [
        [np.cos(angle), 0, np.sin(angle)],
        [0, 1, 0],
        [-np.sin(angle), 0, np.cos(angle)],
    ]
    worst = 0.0
    for centre in ([160.0, 160.0], [60.0, 90.0], [250.0, 270.0]):
        pix = np.array(centre) + offsets
        world = pixel_directions(fisheye, pix[:, 0], pix[:, 1]) * 2.0  # a plane at z = 2
        uv, _ = project_camera(fisheye, world_to_camera(world, other))
        assert np.abs(weights[probes] - np.eye(9)).max() < 1e-12  # exact at the probes
        worst = max(worst, float(np.abs(weights @ uv[probes] - uv).max()))
    assert worst < 1e-3, worst
