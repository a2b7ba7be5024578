"""centerline `prior: auto`: the prior is chosen from how well each candidate predicts the
depth of the SfM points along the cameras' rays, and none is used when none predicts them.

Inputs are analytic scenes with exact truth: a tube, an ellipsoid cavity, and a scene that is
neither (a wavy sheet far ahead of a short camera path, like C3VD's view down a bending lumen).
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

from endopipe.stages.centerline.cavity import fit_cavity
from endopipe.stages.centerline.choose import (
    choose_prior,
    empty_core,
    point_reach,
    reaching_margin,
    score_prior,
)
from endopipe.stages.centerline.config import CenterlineConfig
from endopipe.stages.centerline.prior import FreePrior, LumenPrior, load_prior, save_prior
from endopipe.stages.centerline.tube import fit_tube
from endopipe.stages.nerf.auto_settings import (
    free_scene_settings,
    still_camera_settings,
    weigh_prior,
)
from endopipe.stages.nerf.bounds import PriorBounds
from endopipe.stages.nerf.config import NerfConfig
from endopipe.stages.nerf.scene import SceneBox

CFG = CenterlineConfig()


def _observe(cams: np.ndarray, pts: np.ndarray, per_cam: int, rng) -> tuple:
    """Each camera observes `per_cam` random points: (origins, points) of the observations."""
    idx = rng.integers(0, len(pts), (len(cams), per_cam))
    return np.repeat(cams, per_cam, 0), pts[idx.ravel()], np.repeat(np.arange(len(cams)), per_cam)


def _candidates(cams, views, pts) -> dict[str, LumenPrior]:
    return {
        "tube": fit_tube(cams, views, pts, CFG).prior(),
        "cavity": fit_cavity(cams, views, pts, CFG).prior(),
    }


def straight_tube(rng):
    z = rng.uniform(5, 60, 4000)
    phi = rng.uniform(0, 2 * np.pi, len(z))
    pts = np.stack([10 * np.cos(phi), 10 * np.sin(phi), z], 1) + rng.normal(0, 0.2, (len(z), 3))
    cams = np.stack([np.zeros(30), np.zeros(30), np.linspace(0, 30, 30)], 1)
    views = np.tile([0.0, 0.0, 1.0], (30, 1))
    return cams, views, pts


def ellipsoid_cavity(rng):
    d = rng.normal(size=(4000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = d * np.array([40.0, 30.0, 25.0]) + rng.normal(0, 0.2, d.shape)
    t = np.linspace(0, 1, 30)
    cams = np.stack([-10 + 20 * t, 3 * np.sin(6 * t), np.zeros(30)], 1)
    views = np.tile([1.0, 0.0, 0.0], (30, 1))
    return cams, views, pts


def neither(rng):
    """A short path looking at a wavy sheet 60-100 units ahead (no wall around the cameras)."""
    xy = rng.uniform(-60, 60, (4000, 2))
    z = 80 + 20 * np.sin(xy[:, 0] / 15) * np.cos(xy[:, 1] / 20)
    pts = np.concatenate([xy, z[:, None]], 1)
    cams = np.stack([np.linspace(0, 3, 30), np.zeros(30), np.linspace(0, 5, 30)], 1)
    views = np.tile([0.0, 0.0, 1.0], (30, 1))
    return cams, views, pts


def test_auto_picks_the_shape_that_predicts_the_points() -> None:
    rng = np.random.default_rng(0)
    for scene, want in ((straight_tube, "tube"), (ellipsoid_cavity, "cavity")):
        cams, views, pts = scene(rng)
        origins, seen, _ = _observe(cams, pts, 80, rng)
        choice = choose_prior(_candidates(cams, views, pts), origins, seen, 0.25, 0.5)
        fit = {s.kind: s.inlier_fraction for s in choice.scores}
        assert choice.kind == want, choice.reason
        assert fit[want] > 0.9, choice.reason
        assert choice.weight == fit[want] and not choice.forced
        # the user forces the shape that fits worse (below min_fit 0.9, the other above):
        # the points contradict it, so the shape that fits is used, and the reason says so
        wrong = "cavity" if want == "tube" else "tube"
        cands = _candidates(cams, views, pts)
        yielded = choose_prior(cands, origins, seen, 0.25, 0.9, forced=wrong)
        assert fit[wrong] < 0.9 and yielded.kind == want and yielded.weight == fit[want]
        assert "contradict" in yielded.reason and "centerline.insist=true" in yielded.reason
        # ... unless the user insists: kept at full weight, called doubtful, and the grids
        # sized by the shape that fits
        forced = choose_prior(cands, origins, seen, 0.25, 0.9, forced=wrong, insist=True)
        assert forced.kind == wrong and forced.weight == 1.0 and forced.forced
        assert "doubtful: it predicts only" in forced.reason and want in forced.reason
        assert forced.scale_from == want
        right = choose_prior(cands, origins, seen, 0.25, 0.9, forced=want)
        assert "doubtful" not in right.reason and right.scale_from is None and right.forced


def test_auto_uses_no_prior_when_none_fits_and_a_forced_one_has_its_full_weight() -> None:
    rng = np.random.default_rng(1)
    cams, views, pts = neither(rng)
    origins, seen, _ = _observe(cams, pts, 80, rng)
    cands = _candidates(cams, views, pts)
    choice = choose_prior(cands, origins, seen, 0.25, 0.5)
    assert choice.kind == "none" and choice.weight == 0.0, choice.reason
    assert "no prior fits" in choice.reason
    forced = choose_prior(cands, origins, seen, 0.25, 0.5, forced="tube")
    assert forced.kind == "tube" and forced.forced and forced.weight == 1.0
    assert "set by the config" in forced.reason and "tube" in forced.reason


def _tube_and_wall_rays(seed: int, n: int):
    """The fitted straight tube (radius 10) and n rays from a point on its axis to its wall."""
    rng = np.random.default_rng(seed)
    cams, views, pts = straight_tube(rng)
    tube = _candidates(cams, views, pts)["tube"]
    o = np.zeros((n, 3)) + np.array([0, 0, 10.0])
    phi = rng.uniform(0, 2 * np.pi, n)
    wall = np.stack([10 * np.cos(phi), 10 * np.sin(phi), np.full(n, 25.0)], 1)
    return tube, o, wall


def test_score_is_the_ratio_of_wall_exit_to_point_distance() -> None:
    """A tube of radius 10 seen from its axis: points on the wall score 1, points at twice the
    distance score a median ratio of 0.5 and no inliers."""
    tube, o, wall = _tube_and_wall_rays(2, 500)
    assert score_prior(tube, o, wall, 0.25).inlier_fraction > 0.95
    far = o + 2 * (wall - o)
    s = score_prior(tube, o, far, 0.25)
    assert s.inlier_fraction < 0.05 and abs(s.median_ratio - 0.5) < 0.05


def test_sampling_reaches_past_a_wall_that_fits_only_some_points(tmp_path: Path) -> None:
    """A tube that predicts 70% of the points, the rest at 3x its wall (C3VD: a quarter of
    the points lay beyond the inflated wall, and their rays ended short of them): the margin
    that holds 90% of the points is about 2 (3x the wall); with every point on the wall it
    is about 0, and it travels with the saved prior to the NeRF's bounds."""
    tube, o, wall = _tube_and_wall_rays(3, 1000)
    assert reaching_margin(tube, o, wall, 0.9) < 0.02
    seen = wall.copy()
    seen[700:] = o[700:] + 3 * (wall[700:] - o[700:])
    tube.margin = reaching_margin(tube, o, seen, 0.9)
    assert abs(tube.margin - 2.0) < 0.05
    save_prior(tube, tmp_path / "prior.npz")
    back = load_prior(tmp_path / "prior.npz")
    assert back.margin == tube.margin
    cfg = NerfConfig()
    box = SceneBox(np.zeros(3), np.eye(3), 1.0, np.full(3, -100.0), np.full(3, 100.0))
    pb = PriorBounds(back, box, cfg)
    assert pb.margin == back.margin > cfg.sampling.bounds_margin
    d = torch.tensor(seen[700:710] - o[700:710], dtype=torch.float32)
    _, far, _ = pb.bounds(torch.tensor(o[700:710], dtype=torch.float32), d, pb.margin)
    assert (far >= 0.99).all()  # every such ray is sampled out to its point (t = 1)


def test_the_empty_core_shrinks_to_leave_out_tissue_the_points_place_inside_it(
    tmp_path: Path,
) -> None:
    """Points on the wall leave the whole core empty (limit about 1). With 8% of them at 0.3 of the
    radius from the axis (C3VD: 8% of its observations lay in the tube's half-radius core,
    where a fold juts into the lumen) the core L_prior empties must stay narrower than 0.3;
    the limit travels with the saved prior and bounds the NeRF's core."""
    tube, _, wall = _tube_and_wall_rays(4, 1000)
    radius = float(np.median(tube.radius_at(torch.as_tensor(wall, dtype=torch.float32))))
    assert empty_core(tube, wall, 0.02) > 0.9  # the fitted wall: about the true one
    pts = wall.copy()
    inner = pts[:80].copy()
    inner[:, :2] *= 0.3 * radius / np.linalg.norm(inner[:, :2], axis=1, keepdims=True)
    pts[:80] = inner
    limit = empty_core(tube, pts, 0.02)
    assert 0.2 < limit < 0.3, limit
    assert (
        float(tube.in_core(torch.as_tensor(pts, dtype=torch.float32), limit).float().mean()) <= 0.02
    )
    tube.core_limit = limit
    save_prior(tube, tmp_path / "prior.npz")
    assert load_prior(tmp_path / "prior.npz").core_limit == limit
    assert empty_core(tube, pts, 0.1) > 0.9  # a tolerance above the 8% inside


def test_reach_is_per_frame_and_free_prior_rays_reach_it(tmp_path: Path) -> None:
    c2w = {0: np.eye(4), 1: np.eye(4)}
    c2w[1][:3, 3] = [0, 0, 50.0]
    pts = np.array([[0, 0, d] for d in np.linspace(10, 100, 50)], float)
    frames = np.array([0] * 25 + [1] * 25)
    # frame 0 saw the near half (10-55), frame 1 the far half (56-100) from z=50: 6-50 away
    reach = point_reach(c2w, frames, pts, percentile=100)
    assert abs(reach - 55.0) < 1.0
    prior = FreePrior(np.zeros(3), 5.0, 1.25 * reach, 30.0)
    d = torch.tensor([[0.0, 0.0, 2.0], [0.6, 0.0, 0.8]])
    near, far = prior.ray_bounds(torch.zeros(2, 3), d, near_fraction=0.05)
    np.testing.assert_allclose((far * d.norm(dim=-1)).numpy(), 1.25 * reach, rtol=1e-5)
    assert (near * d.norm(dim=-1) < 1.0).all()
    assert not prior.in_core(torch.zeros(4, 3)).any()
    save_prior(prior, tmp_path / "prior.npz")
    back = load_prior(tmp_path / "prior.npz")
    assert isinstance(back, FreePrior) and back.weight == 0.0
    assert back.reach == prior.reach and back.depth == 30.0 and back.typical_radius == 5.0


def test_prior_weight_scales_l_prior_and_zero_turns_it_off() -> None:
    cfg = NerfConfig()
    rng = np.random.default_rng(0)
    cams, views, pts = straight_tube(rng)
    tube = fit_tube(cams, views, pts, CFG).prior()
    tube.weight = 0.5
    half = weigh_prior(cfg, tube, lambda _m: None)
    assert half.loss.lambda_prior == cfg.loss.lambda_prior * 0.5 and half.loss.prior
    off = weigh_prior(cfg, FreePrior(np.zeros(3), 1.0, 10.0, 5.0), lambda _m: None)
    assert not off.loss.prior
    assert cfg.loss.prior and cfg.loss.lambda_prior == NerfConfig().loss.lambda_prior


def test_a_moving_camera_without_a_prior_gets_the_free_scene_field() -> None:
    """No wall bounds a free scene (the sinus window): its grid is warped, its shading loses
    n.l (its normals are the density's noise: held-out 18.8 dB with it, 24.2 without on a
    sinus stretch), each frame gets an exposure and the albedo changes with time. A prior, or a
    still camera, keeps the settings as they were, the exposure resolved to off."""
    cfg = NerfConfig()
    free = FreePrior(np.zeros(3), 1.0, 10.0, 5.0)
    moving = SimpleNamespace(still=False, one_pair=False)
    lines: list[str] = []
    out = free_scene_settings(cfg, free, moving, lines.append)
    assert out.field.warp is True and out.field.appearance_time is True
    assert out.shading.normal_term is False and out.shading.exposure is True
    assert len(lines) == 1 and "no lumen prior" in lines[0]
    rng = np.random.default_rng(0)
    cams, views, pts = straight_tube(rng)
    tube = fit_tube(cams, views, pts, CFG).prior()
    still = SimpleNamespace(still=True, one_pair=False)
    for prior, poses in ((tube, moving), (free, still)):
        kept = free_scene_settings(cfg, prior, poses, lines.append)
        assert kept.field == cfg.field and kept.shading.normal_term is True
        assert kept.shading.exposure is False
    assert len(lines) == 1
    # What the user set is kept: the warp off and an albedo without time stay so.
    cfg.field.warp, cfg.field.appearance_time, cfg.shading.exposure = False, False, False
    own = free_scene_settings(cfg, free, moving, lines.append)
    assert own.field.warp is False and own.field.appearance_time is False
    assert own.shading.exposure is False


def test_a_still_camera_trains_longer_and_a_moving_one_does_not() -> None:
    """A still camera's held-out frames are new times from the same view, and more steps bring
    them closer (the cutting clip); a moving camera's more steps fit only its training frames
    (the sinus window). A factor of 1 (the paper preset's) keeps the steps as given."""
    cfg = NerfConfig()
    lines: list[str] = []
    moving = SimpleNamespace(still=False, one_pair=False, motion=None)
    still = SimpleNamespace(still=True, one_pair=False, motion=None)
    assert still_camera_settings(cfg, moving, lines.append).train.steps == cfg.train.steps
    assert not lines
    longer = still_camera_settings(cfg, still, lines.append)
    assert longer.train.steps == round(4.0 * cfg.train.steps) == 6000
    assert any("6000 steps" in line and "still camera" in line for line in lines)
    # its time budget grows with its steps (a machine of the reference speed trains them all)
    assert longer.train.time_budget_s == 4.0 * cfg.train.time_budget_s
    assert any(f"within {4.0 * cfg.train.time_budget_s:g} s" in line for line in lines)
    unbounded = cfg.model_copy(
        update={"train": cfg.train.model_copy(update={"time_budget_s": None})}
    )
    assert still_camera_settings(unbounded, still, lines.append).train.time_budget_s is None
    # the grid: unwarped over a still scene, over the view's frustum where tissue moves
    assert longer.field.warp is False
    pulled = SimpleNamespace(still=True, one_pair=False, motion=SimpleNamespace(scene="moving"))
    assert still_camera_settings(cfg, pulled, lines.append).field.warp == "frustum"
    cfg.train.still_steps = 1.0
    kept = still_camera_settings(cfg, still, lines.append).train
    assert kept.steps == cfg.train.steps and kept.time_budget_s == cfg.train.time_budget_s
