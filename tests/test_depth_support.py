"""Views maps: a depth pixel counts the nearby views whose own depth agrees with it."""

from __future__ import annotations

import numpy as np

from endopipe.stages.camera import Camera
from endopipe.stages.depth.support import consistent_views
from endopipe.stages.poses.lens import past_fitted_radius

CAMERA = Camera(width=80, height=64, fx=60.0, fy=60.0, cx=39.5, cy=31.5)
WALL_Z = 10.0


def _walk(n: int, step: float = 0.3) -> dict[int, np.ndarray]:
    """n cameras sliding along x, looking down +z at a wall (z = WALL_Z)."""
    poses = {}
    for i in range(n):
        c2w = np.eye(4)
        c2w[0, 3] = step * i
        poses[i] = c2w
    return poses


def _wall_depths(n: int) -> dict[int, np.ndarray]:
    return {i: np.full((CAMERA.height, CAMERA.width), WALL_Z, np.float32) for i in range(n)}


def test_a_wall_every_view_sees_is_seen_again_and_a_wrong_map_is_not() -> None:
    poses, depths = _walk(9), _wall_depths(9)
    depths[3] = depths[3] * 1.2  # one frame puts the wall 20% too far
    counts = consistent_views(depths, poses, CAMERA, neighbours=4, tolerance=0.05)
    centre = (slice(24, 40), slice(30, 50))  # every neighbour sees these points
    assert np.all(counts[3][centre] == 0)  # no other view confirms the wrong map
    assert np.all(counts[1][centre] == 3)  # frame 3 is one of frame 1's four: it disagrees
    assert np.all(counts[8][centre] == 4)  # its four neighbours (4 to 7) all agree


def test_no_depth_has_no_views_and_points_out_of_view_count_for_nothing() -> None:
    poses, depths = _walk(3, step=4.0), _wall_depths(3)
    depths[0][:, :10] = 0.0
    counts = consistent_views(depths, poses, CAMERA, neighbours=2, tolerance=0.05)
    assert counts[0].dtype == np.uint8 and np.all(counts[0][:, :10] == 0)
    # 4 units to the side at 10 deep is 24 px: frame 0's left part is in no other view
    assert np.all(counts[0][:, 10:20] == 0) and np.all(counts[0][:, -10:] >= 1)


def test_pixels_past_the_lens_fitted_radius_are_flagged_at_the_maps_size() -> None:
    assert past_fitted_radius(CAMERA, None, CAMERA.width) is None  # a given lens: nothing
    # fitted within 20 px of an image twice as wide: 10 px here (and 8 px for a share of 0.8)
    assert past_fitted_radius(CAMERA, 20.0, 2 * CAMERA.width, 0.8)[31, 39 + 9]
    past = past_fitted_radius(CAMERA, 20.0, 2 * CAMERA.width)
    v, u = np.nonzero(past)
    assert past.shape == (CAMERA.height, CAMERA.width)
    assert np.hypot(u - CAMERA.cx, v - CAMERA.cy).min() > 10.0
    assert not past[31, 39 + 9] and past[31, 39 + 11]
