"""Honest unknowns (issue 14): a ray that meets no surface gets no depth (0), and only an
explicit `depth.fill` gives it the prior's wall, which the mesh still never fuses."""

from __future__ import annotations

import numpy as np

from endopipe.stages.camera import Camera
from endopipe.stages.centerline.prior import TubePrior
from endopipe.stages.nerf.baked import BakedSurface


def _half_wall() -> tuple[Camera, BakedSurface, TubePrior]:
    """A camera on a tube's axis looking down it; a baked quad covers the left half of the
    view at z = 5, the right half sees nothing baked (and no field to ask)."""
    k = Camera(width=40, height=30, fx=30.0, fy=30.0, cx=19.5, cy=14.5)
    quad = np.array([[-50, -50, 5.0], [0, -50, 5.0], [0, 50, 5.0], [-50, 50, 5.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    tube = TubePrior(np.stack([np.zeros(50), np.zeros(50), np.linspace(-10, 100, 50)], 1), 3.0)
    return k, BakedSurface(quad, faces, tube, model=None), tube


def test_rays_that_find_no_surface_have_no_depth() -> None:
    k, baked, _ = _half_wall()
    out = baked.render_depth(k, np.eye(4))
    left, right = out["depth"][:, :18], out["depth"][:, 22:]
    np.testing.assert_allclose(left, 5.0, atol=1e-4)
    assert (right == 0).all() and (out["opacity"][:, 22:] == 0).all()
    assert (out["opacity"][:, :18] == 1).all()


def test_fill_is_an_opt_in_guess_from_the_prior_with_no_opacity() -> None:
    k, baked, tube = _half_wall()
    out = baked.render_depth(k, np.eye(4), fill=True)
    right = out["depth"][:, 22:]
    assert (right > 0).all() and (out["opacity"][:, 22:] == 0).all()
    # the guess is where each ray leaves the tube's wall (radius 3, the camera on the axis;
    # ray_bounds' default margin 0.25 inflates it), capped at 6 radii along the ray
    u = np.arange(22, 40)
    v = np.arange(30)
    rho = np.hypot((u[None, :] - 19.5) / 30.0, (v[:, None] - 14.5) / 30.0)
    expected_z = np.minimum(3.0 * 1.25 / rho, 6 * 3.0 / np.sqrt(1 + rho**2))
    np.testing.assert_allclose(right, expected_z, rtol=0.02)
