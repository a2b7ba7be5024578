"""The lumen priors (stages/centerline/prior/) on analytic shapes: tube distance, core, ray
bounds, ellipsoid, npz."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

from endopipe.stages.camera import look_at
from endopipe.stages.centerline.prior import (
    EllipsoidPrior,
    TubePrior,
    load_prior,
    save_prior,
)

RHO, R = 60.0, 15.0  # circular-arc centre line of radius RHO in the z = 0 plane, tube radius R
ARC = np.pi / 1.5


def arc_tube(open_ends: bool = False, radius: float | np.ndarray = R) -> TubePrior:
    th = np.linspace(0.0, ARC, 300)
    pts = np.stack([RHO * np.cos(th), RHO * np.sin(th), np.zeros_like(th)], 1)
    return TubePrior(pts, radius, open_ends=open_ends)


def arc_points(rng: np.random.Generator, n: int, d_max: float, margin: float = 0.1):
    """Points at distance d from the arc, their angle along it away from its ends."""
    ang = rng.uniform(margin, ARC - margin, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    d = rng.uniform(0, d_max, n)
    centre = np.stack([RHO * np.cos(ang), RHO * np.sin(ang), 0 * ang], 1)
    normal = np.stack([np.cos(ang), np.sin(ang), 0 * ang], 1)
    offset = np.cos(phi)[:, None] * normal + np.sin(phi)[:, None] * np.array([0.0, 0.0, 1.0])
    return centre, offset, d, ang


def true_arc_distance(x: np.ndarray) -> np.ndarray:
    return np.sqrt((np.hypot(x[:, 0], x[:, 1]) - RHO) ** 2 + x[:, 2] ** 2)


def test_straight_tube_signed_distance_is_exact() -> None:
    z = np.linspace(0.0, 100.0, 200)
    tube = TubePrior(np.stack([0 * z, 0 * z, z], 1), 10.0)
    x = np.random.default_rng(0).uniform([-25, -25, 5], [25, 25, 95], (5000, 3))
    sd = tube.signed_distance(torch.tensor(x, dtype=torch.float32)).numpy()
    np.testing.assert_allclose(sd, np.hypot(x[:, 0], x[:, 1]) - 10.0, atol=1e-3)
    s = tube.nearest_param(torch.tensor(x)).numpy()
    np.testing.assert_allclose(s, x[:, 2], atol=1e-6)


def test_arc_tube_signed_distance_within_one_percent_inside_and_outside() -> None:
    tube = arc_tube()
    rng = np.random.default_rng(1)
    centre, offset, d, _ = arc_points(rng, 20000, 2.0 * R)
    x = centre + d[:, None] * offset
    sd = tube.signed_distance(torch.tensor(x, dtype=torch.float32)).numpy()
    true = true_arc_distance(x) - R
    assert (true < 0).sum() > 5000 and (true > 0).sum() > 5000
    assert np.abs(sd - true).max() < 0.01 * R
    # The grid's local line agrees with brute force on the polyline.
    exact = tube.closest(torch.tensor(x), exact=True)["dist"].numpy()
    assert np.abs(exact - true_arc_distance(x)).max() < 0.01 * R
    # Shapes follow the input's leading dimensions.
    assert tube.signed_distance(torch.tensor(x[:24]).reshape(2, 3, 4, 3)).shape == (2, 3, 4)


def test_varying_radius_and_in_core() -> None:
    th = np.linspace(0.0, ARC, 300)
    radius = 10.0 + 5.0 * th / ARC  # 10 -> 15 along the arc
    tube = arc_tube(radius=radius)
    rng = np.random.default_rng(2)
    centre, offset, d, ang = arc_points(rng, 5000, 1.2 * R)
    x = torch.tensor(centre + d[:, None] * offset)
    r_true = 10.0 + 5.0 * ang / ARC
    np.testing.assert_allclose(tube.radius_at(x).numpy(), r_true, rtol=2e-3)
    # Arc length: refined (the default) and first-order (the local line of the grid cell).
    np.testing.assert_allclose(tube.nearest_param(x).numpy(), RHO * ang, atol=0.02 * R)
    coarse = tube.closest(x, refine=False)["s"].numpy()
    np.testing.assert_allclose(coarse, RHO * ang, atol=0.04 * R)
    core = tube.in_core(x, fraction=0.5).numpy()
    clear = np.abs(d - 0.5 * r_true) > 0.02 * r_true
    np.testing.assert_array_equal(core[clear], (d < 0.5 * r_true)[clear])
    sd = tube.signed_distance(x).numpy()
    np.testing.assert_allclose(sd, d - r_true, atol=0.01 * R)


def test_ray_bounds_axis_to_wall() -> None:
    tube = arc_tube()
    rng = np.random.default_rng(3)
    centre, offset, _, _ = arc_points(rng, 4000, 0.0, margin=0.35)
    o = torch.tensor(centre, dtype=torch.float32)
    d = torch.tensor(offset, dtype=torch.float32)
    margin = 0.2
    near, far = tube.ray_bounds(o, d, margin=margin)
    np.testing.assert_allclose(far.numpy(), R * (1 + margin), atol=0.01 * R)
    assert bool((near > 0).all()) and bool((near < far).all())
    # Unnormalised directions: t is in their units.
    near2, far2 = tube.ray_bounds(o, 2.0 * d, margin=margin)
    np.testing.assert_allclose(far2.numpy(), far.numpy() / 2.0, rtol=1e-5)
    np.testing.assert_allclose(near2.numpy(), near.numpy() / 2.0, rtol=1e-5)


def test_ray_bounds_oblique_rays_find_the_first_exit() -> None:
    tube = arc_tube()
    rng = np.random.default_rng(4)
    centre, offset, d0, _ = arc_points(rng, 3000, 0.5 * R, margin=0.5)
    origins = centre + d0[:, None] * offset
    dirs = rng.normal(size=(3000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    o = torch.tensor(origins, dtype=torch.float32)
    d = torch.tensor(dirs, dtype=torch.float32)
    margin, cap = 0.2, 6 * R
    _, far = tube.ray_bounds(o, d, margin=margin, max_far=cap)
    capped = far.numpy() >= cap - 1e-4
    x = (o + far[:, None] * d).double().numpy()
    # The analytic truth is the torus: judge exits alongside the arc, not past its end caps.
    along = _interior(x)
    assert along.mean() > 0.8
    wall = true_arc_distance(x) - R * (1 + margin)
    assert np.abs(wall[~capped & along]).max() < 0.01 * R
    # Nothing before far is outside the inflated wall (the first exit, not a later one).
    ts = torch.linspace(0, 1, 64)[None, :, None] * far[:, None, None] * 0.999
    xs = (o[:, None] + ts * d[:, None]).reshape(-1, 3).double().numpy()
    xs = xs[_interior(xs)]
    assert (true_arc_distance(xs) - R * (1 + margin)).max() < 0.01 * R


def _interior(x: np.ndarray, margin: float = 0.02) -> np.ndarray:
    ang = np.arctan2(x[:, 1], x[:, 0])
    return (ang > margin) & (ang < ARC - margin)


def test_ray_bounds_frame_speed_and_open_ends() -> None:
    """82k rays of a 320x256 frame looking down a bending lumen (timing printed, not asserted)."""
    th = np.linspace(0.0, np.pi / 2, 300)
    rho = 120.0
    tube = TubePrior(np.stack([rho * np.cos(th), rho * np.sin(th), 0 * th], 1), R)
    ang = 1.3  # near the end: many rays look past it, down the open end
    eye = np.array([rho * np.cos(ang), rho * np.sin(ang), 0.0]) + np.array([2.0, 0.0, 1.0])
    tangent = np.array([-np.sin(ang), np.cos(ang), 0.0])
    c2w = look_at(eye, eye + 25 * tangent, np.array([0.0, 0.0, 1.0]))
    u, v = np.meshgrid(np.arange(320), np.arange(256))
    cam = np.stack([(u - 160) / 160, (v - 128) / 160, np.ones_like(u)], -1).reshape(-1, 3)
    d = torch.tensor(cam @ c2w[:3, :3].T, dtype=torch.float32)
    o = torch.tensor(eye, dtype=torch.float32).expand_as(d)
    tube.ray_bounds(o, d)  # warm-up
    t0, c0 = time.perf_counter(), time.process_time()
    near, far = tube.ray_bounds(o, d, margin=0.2)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    print(f"\nray_bounds, {len(d)} rays: {1000 * wall:.1f} ms wall, {1000 * cpu:.1f} ms CPU")
    assert bool(torch.isfinite(far).all()) and bool((near < far).all())
    cap = tube.far_radii * R
    t = far * d.norm(dim=-1)
    assert float(t.max()) <= cap + 1e-3
    # Rays down the open end are not stopped by a cap on the tube: some reach the far cap.
    assert bool((t > cap - 1e-3).any())


def test_ray_bounds_origin_outside() -> None:
    z = np.linspace(0.0, 100.0, 100)
    tube = TubePrior(np.stack([0 * z, 0 * z, z], 1), 10.0)
    o = torch.tensor([[-30.0, 0.0, 50.0], [-30.0, 0.0, 50.0]])
    d = torch.tensor([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    near, far = tube.ray_bounds(o, d, margin=0.0)
    assert abs(float(far[0]) - 40.0) < 1e-3  # through the tube to its far wall
    assert bool((near <= far).all()) and bool(torch.isfinite(far).all())


def test_ellipsoid_prior() -> None:
    from scipy.spatial import cKDTree
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    a, c = np.array([30.0, 20.0, 12.0]), np.array([1.0, 2.0, 3.0])
    ell = EllipsoidPrior(c, a[[1, 0, 2]], rot[:, [1, 0, 2]])  # axes in any order
    np.testing.assert_allclose(ell.axes, a)
    th, ph = np.meshgrid(np.linspace(0, np.pi, 400), np.linspace(0, 2 * np.pi, 800))
    surf = (
        np.stack(
            [a[0] * np.cos(th), a[1] * np.sin(th) * np.cos(ph), a[2] * np.sin(th) * np.sin(ph)], -1
        ).reshape(-1, 3)
        @ rot.T
        + c
    )
    x = c + np.random.default_rng(5).normal(size=(300, 3)) * 15
    brute, _ = cKDTree(surf).query(x)
    inside = ((((x - c) @ rot) / a) ** 2).sum(1) < 1
    sd = ell.signed_distance(torch.tensor(x)).numpy()
    np.testing.assert_allclose(sd, np.where(inside, -brute, brute), atol=0.12)  # 0.01 x 12
    np.testing.assert_array_equal(ell.in_core(torch.tensor(x), 1.0).numpy(), inside)
    o = torch.tensor(c).expand(3, 3)
    _, far = ell.ray_bounds(o, torch.tensor(rot.T), margin=0.1)
    np.testing.assert_allclose(far.numpy(), 1.1 * a, rtol=1e-6)


def test_save_load_round_trip(tmp_path) -> None:
    tube = arc_tube(open_ends=True, radius=np.linspace(10, 15, 300))
    save_prior(tube, tmp_path / "prior.npz")
    back = load_prior(tmp_path / "prior.npz")
    assert isinstance(back, TubePrior) and back.open_ends
    x = torch.tensor(np.random.default_rng(6).uniform(-80, 80, (1000, 3)))
    np.testing.assert_allclose(back.signed_distance(x).numpy(), tube.signed_distance(x).numpy())
    ell = EllipsoidPrior([0, 0, 0], [3, 2, 1])
    assert ell.typical_radius == pytest.approx(6 ** (1 / 3))  # its own radius
    ell.unit = 0.5  # a forced prior that fits badly: the scale of the shape that fits
    save_prior(ell, tmp_path / "cavity.npz")
    back = load_prior(tmp_path / "cavity.npz")
    assert isinstance(back, EllipsoidPrior)
    np.testing.assert_allclose(back.axes, [3, 2, 1])
    assert back.typical_radius == 0.5 and back.own_radius == pytest.approx(6 ** (1 / 3))


def test_dtypes_and_numpy_input() -> None:
    tube = arc_tube()
    x = np.array([[RHO, 0.0, 5.0], [RHO + 20.0, 0.0, 0.0]])
    for arr in (x, torch.tensor(x), torch.tensor(x, dtype=torch.float32)):
        sd = tube.signed_distance(arr)
        assert isinstance(sd, torch.Tensor)
        np.testing.assert_allclose(sd.double().numpy(), [-10.0, 5.0], atol=1e-3)


def test_signed_distance_gradients_are_wall_normals() -> None:
    """The NeRF loss may differentiate the prior: |grad sd| = 1, along the wall's normal."""
    tube = arc_tube()
    x = torch.tensor([[RHO + 3.0, 0.0, 4.0]], requires_grad=True)
    tube.signed_distance(x).sum().backward()
    np.testing.assert_allclose(x.grad.numpy(), [[0.6, 0.0, 0.8]], atol=1e-3)
    ell = EllipsoidPrior([0, 0, 0], [3, 2, 1])
    x = torch.tensor([[0.5, 0.2, 0.1], [4.0, 0.0, 0.0]], requires_grad=True)
    ell.signed_distance(x).sum().backward()
    np.testing.assert_allclose(x.grad.norm(dim=1).numpy(), 1.0, atol=1e-5)
    np.testing.assert_allclose(x.grad[1].numpy(), [1.0, 0.0, 0.0], atol=1e-6)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda() -> None:
    tube = arc_tube()
    x = torch.tensor([[RHO, 0.0, 5.0]], device="cuda")
    assert tube.signed_distance(x).device.type == "cuda"
    o = torch.tensor([[RHO, 0.0, 0.0]], device="cuda")
    _, far = tube.ray_bounds(o, torch.tensor([[0.0, 0.0, 1.0]], device="cuda"), margin=0.0)
    assert abs(float(far.cpu()[0]) - R) < 0.01 * R


def test_sampling_reaches_past_a_contradicted_wall_but_the_wall_stays_where_it_is() -> None:
    """The cavity preset on a colon: the ellipsoid ends rays the scene continues past. Samples
    reach the farthest SfM points (`reach`); the wall the prior pulls towards does not move. A
    prior that fits keeps its own bounds."""
    from endopipe.stages.nerf.bounds import PriorBounds
    from endopipe.stages.nerf.config import NerfConfig
    from endopipe.stages.nerf.scene import SceneBox

    box = SceneBox.fit(np.zeros((1, 3)), 10.0, np.array([[-15.0] * 3, [15.0] * 3]))
    o = box.world_to_scene(torch.zeros(1, 3))
    rotation = torch.as_tensor(box.rotation, dtype=torch.float32)
    d = torch.tensor([[0.0, 0.0, 1.0]]) @ rotation / box.scale  # t in world units
    ell = EllipsoidPrior([0, 0, 0], [10, 10, 10])
    ell.reach = 40.0
    fitting = PriorBounds(ell, box, NerfConfig())
    assert fitting.bounds(o, d, 0.5)[1].item() == pytest.approx(15.0)  # the inflated wall
    ell.unit = 3.0  # forced, and the SfM points say another shape (of radius 3) fits
    pb = PriorBounds(ell, box, NerfConfig())
    _, far, _ = pb.bounds(o, d, 0.5)
    _, wall, has_wall = pb.bounds(o, d, 0.0, wall=True)
    assert far.item() == pytest.approx(40.0) and wall.item() == pytest.approx(10.0)
    assert bool(has_wall.item())


def test_prior_bounds_do_not_end_rays_at_the_extrapolated_tube() -> None:
    """Past the ends of its centerline the tube's wall is its last segment continued straight:
    a guess. A ray that leaves it there is sampled up to the cap (the far lumen of a bending
    colon lies beyond that straight wall); a ray that leaves it along the curve keeps the wall.
    `sampling.open_tube_ends=false` restores the extrapolated wall."""
    from endopipe.stages.nerf.bounds import PriorBounds
    from endopipe.stages.nerf.config import NerfConfig
    from endopipe.stages.nerf.scene import SceneBox

    pts = np.stack([np.zeros(50), np.zeros(50), np.linspace(0.0, 40.0, 50)], 1)
    tube = TubePrior(pts, 10.0, open_ends=True)
    box = SceneBox.fit(np.zeros((1, 3)), 10.0, np.array([[-200.0] * 3, [200.0] * 3]))
    rotation = torch.as_tensor(box.rotation, dtype=torch.float32)
    o = box.world_to_scene(torch.tensor([[0.0, 0.0, 20.0]] * 2))
    ahead = [0.2, 0.0, 1.0]  # leaves the straight wall (radius 15) at z = 20 + 75: past the end
    aside = [1.0, 0.0, 0.2]  # leaves it at z = 23: beside the curve
    d = torch.tensor([ahead, aside]) @ rotation / box.scale  # t in world units along the axis
    cfg = NerfConfig()
    cap = cfg.sampling.far_radii * 10.0
    _, far, is_wall = PriorBounds(tube, box, cfg).bounds(o, d, 0.5)
    assert far[0].item() == pytest.approx(cap / float(np.hypot(0.2, 1.0)), rel=1e-4)
    assert far[1].item() == pytest.approx(15.0, rel=1e-3) and is_wall.tolist() == [False, True]
    cfg.sampling.open_tube_ends = False
    _, closed, _ = PriorBounds(tube, box, cfg).bounds(o, d, 0.5)
    assert closed[0].item() == pytest.approx(75.0, rel=1e-3)


def test_a_moved_prior_is_the_same_wall_in_the_new_coordinates() -> None:
    """x -> s R x + t: the signed distance at the moved point is s times the old one, for every
    shape (within 2% of the radius: the tube's lookup grid is cut anew), and the lengths it
    carries (reach, unit) scale with it."""
    from scipy.spatial.transform import Rotation

    from endopipe.stages.centerline.prior import FreePrior

    def turn(v: list[float]) -> np.ndarray:
        return Rotation.from_rotvec(v).as_matrix()

    s, r, t = 0.37, turn([0.3, -1.1, 0.5]), np.array([4.0, -2.0, 9.0])
    centre, offset, d, _ = arc_points(np.random.default_rng(3), 500, 1.5 * 20.0)
    x = centre + d[:, None] * offset  # about the wall, where the NeRF asks
    shapes = [
        arc_tube(open_ends=True, radius=np.linspace(10.0, 20.0, 300)),
        EllipsoidPrior([1.0, 2.0, 3.0], [40.0, 25.0, 15.0], turn([0, 0, 0.4])),
        FreePrior([0.0, 1.0, 2.0], 5.0, 80.0, 20.0),
    ]
    for prior in shapes:
        prior.reach, prior.unit, prior.margin, prior.weight = 80.0, 12.0, 0.3, 0.6
        moved = prior.moved(s, r, t)
        assert moved.kind == prior.kind
        before = prior.signed_distance(x).double().numpy()
        after = moved.signed_distance(s * x @ r.T + t).double().numpy()
        np.testing.assert_allclose(after, s * before, atol=s * 0.02 * R, err_msg=prior.kind)
        assert moved.reach == pytest.approx(s * 80.0) and moved.unit == pytest.approx(s * 12.0)
        assert (moved.margin, moved.weight) == (0.3, 0.6)
        assert moved.far_radii == pytest.approx(prior.far_radii)  # a count of radii
