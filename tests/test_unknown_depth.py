"""Honest unknowns: a ray that meets no surface gets no depth (0), and only an
explicit `depth.fill` gives it the prior's wall, which the mesh still never fuses; a ray whose
weight the field spreads as haze gets none either."""

from __future__ import annotations

import numpy as np
import torch

from endopipe.stages.camera import Camera
from endopipe.stages.centerline.prior import TubePrior
from endopipe.stages.nerf.baked import BakedSurface
from endopipe.stages.nerf.render import weight_median_and_spread, weight_spread
from endopipe.stages.nerf.sampling import composite, weight_quantiles


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


def test_weight_quantiles_spread_each_samples_weight_over_its_interval() -> None:
    """Equal weights on [2, 10): the quartiles are 4, 6 and 8 exactly, not the nearest
    samples (a stepped median would make depth maps terraced)."""
    t = torch.linspace(2.0, 9.5, 16)[None]
    w = torch.full((1, 16), 1.0 / 16)
    q = weight_quantiles(t, w, torch.tensor([10.0]), (0.25, 0.5, 0.75))
    torch.testing.assert_close(q, torch.tensor([[4.0, 6.0, 8.0]]), atol=1e-5, rtol=0)


def test_haze_has_a_wide_weight_spread_and_a_wall_a_narrow_one() -> None:
    """What depth.max_spread (0.15) tells apart: a wall 0.2 deep at z 10, and haze of the same
    opacity spread from z 2 to 12 (a ray in front of C3VD's lower-left rim)."""
    t = torch.linspace(1.0, 14.0, 261).expand(2, -1).contiguous()
    wall = ((t[0] >= 10.0) & (t[0] < 10.2)).float() * 15.0
    haze = ((t[1] >= 2.0) & (t[1] < 12.0)).float() * 0.3
    far = torch.full((2,), 14.0)
    w, _ = composite(t, torch.stack([wall, haze]), torch.ones(2), far)
    assert w.sum(1).min() > 0.9  # both opaque: opacity cannot tell them apart
    spread = weight_spread({"t": t, "weights": w}, far)
    assert spread[0] < 0.02 and spread[1] > 0.3


def test_a_rays_median_depth_stays_on_its_wall_where_haze_pulls_the_expected_depth() -> None:
    """depth.field_depth: a wall at z 10 behind faint haze from z 2 (a fifth of the weight):
    the expected depth lands in front of the wall, the median on it."""
    t = torch.linspace(1.0, 14.0, 521)[None].contiguous()
    sigma = ((t >= 2.0) & (t < 10.0)).float() * 0.03 + ((t >= 10.0) & (t < 10.2)).float() * 30.0
    far = torch.full((1,), 14.0)
    w, _ = composite(t, sigma, torch.ones(1), far)
    haze = float(w[0, t[0] < 10.0].sum())
    assert 0.15 < haze < 0.25 and w.sum() > 0.95
    expected = float((w * t).sum() / w.sum())
    median, spread = weight_median_and_spread({"t": t, "weights": w}, far)
    assert abs(float(median[0]) - 10.1) < 0.15  # on the wall
    assert expected < 9.3  # pulled 8% of the depth towards the camera
    assert float(spread[0]) < 0.15  # found: a depth the depth stage keeps


def test_the_depth_read_out_follows_what_trained_the_field() -> None:
    """depth.field_depth auto: the mean where measured depth trained it (it fits that mean),
    the median where nothing did; a nerf folder that did not record it keeps the mean."""
    from types import SimpleNamespace

    from endopipe.stages.depth.config import DepthConfig
    from endopipe.stages.depth.renderer import field_depth

    def nerf(supervised: bool | None) -> SimpleNamespace:
        return SimpleNamespace(summary=SimpleNamespace(depth_supervised=supervised))

    auto = DepthConfig()
    assert field_depth(auto, nerf(False)) == "median"
    assert field_depth(auto, nerf(True)) == "expected"
    assert field_depth(auto, nerf(None)) == "expected"
    assert field_depth(DepthConfig(field_depth="median"), nerf(True)) == "median"
