"""nerf stage: encodings, sampling, training, checkpoint resume, rendering, metrics.

The fast tests use the tiny analytic tube of tests/tube_scene.py; the accuracy run on a
synthetic 60-frame colon is marked slow. The photometric model is in test_nerf_shading.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from endopipe.stages.camera import Camera, pixel_rays
from endopipe.stages.centerline.prior import save_prior
from endopipe.stages.metrics.depth import depth_errors, depth_frame_metrics, depth_sequence_metrics
from endopipe.stages.nerf.auto_settings import regularise_far_view
from endopipe.stages.nerf.config import NerfConfig
from endopipe.stages.nerf.data import holdout_split
from endopipe.stages.nerf.encodings import HashGrid, VMGrid
from endopipe.stages.nerf.field import make_field
from endopipe.stages.nerf.render import density_grid, load_model, render_image, save_model
from endopipe.stages.nerf.sampling import composite, sample_pdf, spaced
from endopipe.stages.nerf.scene import SceneBox
from endopipe.stages.nerf.stage import fit_box
from endopipe.stages.nerf.train import Trainer
from tests.tube_scene import (  # noqa: F401 - one_torch_thread is a fixture
    END_Z,
    RADIUS,
    H,
    W,
    intrinsics,
    one_torch_thread,
    tiny_config,
    tiny_setup,
    tube_frame,
    tube_poses,
    tube_prior,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


# --- pieces -------------------------------------------------------------------------------------


def test_vm_grid_fast_path_matches_and_upsampling_keeps_values():
    g = VMGrid((9, 7, 13), 4)
    x = torch.rand(500, 3) * 2.2 - 1.1
    with_grad = g(x)
    with torch.no_grad():
        fast = g(x)
    assert torch.allclose(with_grad, fast, atol=1e-6)
    with_grad.square().sum().backward()
    assert g.planes.grad is not None and g.planes.grad.abs().sum() > 0
    # Refining 9 -> 17 nodes (2x - 1) keeps the bilinear function exactly.
    fine = g.upsampled((17, 13, 25))
    inside = torch.rand(300, 3) * 2 - 1
    assert torch.allclose(fine(inside), g(inside), atol=1e-5)


@pytest.mark.parametrize("encoding", ["tensorf", "hashgrid", "positional"])
def test_fields_share_one_interface(encoding):
    cfg = NerfConfig().field
    cfg.encoding = encoding
    cfg.hashgrid.log2_size = 12
    cfg.hashgrid.max_res = 64
    cfg.positional.width = 32
    field = make_field(cfg, (2.0, 2.0, 4.0))
    x = torch.rand(64, 3) * 2 - 1
    sigma, feat = field(x)
    albedo = field.decode(feat)
    assert sigma.shape == (64,) and (sigma >= 0).all()
    assert albedo.shape == (64, 3) and ((albedo >= 0) & (albedo <= 1)).all()
    assert field.density(torch.full((2, 3), 1.5)).abs().sum() == 0  # outside the box
    (sigma.sum() + albedo.sum()).backward()
    groups = field.param_groups(0.02, 1e-3)
    assert sum(len(g["params"]) for g in groups) == len(list(field.parameters()))


def test_hashgrid_dense_and_hashed_levels():
    h = HashGrid(levels=4, features=2, log2_size=10, base_res=4, max_res=32)
    assert h.dense[0] and not h.dense[-1]
    out = h(torch.rand(10, 3) * 2 - 1)
    assert out.shape == (10, 8)


def test_sampling_and_compositing():
    near, far = torch.full((4,), 0.5), torch.full((4,), 8.0)
    t = spaced(near, far, 32, "log")
    assert (t[:, 1:] > t[:, :-1]).all() and t.min() >= 0.5 and t.max() <= 8.0
    sigma = torch.zeros(4, 32)
    sigma[:, 20] = 1e4  # an opaque wall at sample 20
    w, _ = composite(t, sigma, torch.ones(4), far)
    assert torch.allclose(w.sum(1), torch.ones(4), atol=1e-4)
    assert torch.allclose((w * t).sum(1), t[:, 20], atol=1e-3)
    fine = sample_pdf(t, w, 16)
    assert ((fine - t[:, 20:21]).abs() < (t[:, 21:22] - t[:, 19:20])).all()


def test_distortion_loss_prefers_one_compact_surface():
    from endopipe.stages.nerf.losses import distortion

    t = torch.linspace(0.0, 4.0, 33)[None]
    far = torch.tensor([4.0])
    compact = torch.zeros_like(t)
    compact[0, 16:18] = 0.5
    spread = torch.zeros_like(t)
    spread[0, 8:24] = 1.0 / 16
    two_walls = torch.zeros_like(t)
    two_walls[0, [4, 28]] = 0.5
    values = [float(distortion(t, w, far)) for w in (compact, spread, two_walls)]
    assert values[0] < values[1] < values[2]


def test_sparse_depth_loss_is_huber_and_ignores_outlier_points():
    from endopipe.stages.nerf.losses import sparse_depth

    target = torch.full((3,), 10.0)
    exact = sparse_depth(target.clone(), target)
    near = sparse_depth(torch.tensor([10.2, 10.0, 10.0]), target)  # 2%: quadratic zone
    far = sparse_depth(torch.tensor([12.0, 10.0, 10.0]), target)  # 20%: linear zone
    assert float(exact) == 0.0 and 0 < float(near) < float(far)
    assert float(far) == pytest.approx((0.2 - 0.025) / 3, rel=1e-5)
    # A point 80% off (a track across a silhouette) gives the field no pull at all.
    depth = torch.tensor([18.0, 10.5, 10.0], requires_grad=True)
    sparse_depth(depth, target).backward()
    assert depth.grad[0] == 0 and depth.grad[1] > 0


def test_depth_metrics():
    gt = np.full((4, 5), 10.0)
    assert depth_errors(gt[gt > 0], gt[gt > 0])["abs_rel"] == 0
    m = depth_frame_metrics(gt * 2, gt)  # a global scale is removed by median scaling
    assert m["abs_rel"] < 1e-12 and m["delta1"] == 1.0 and abs(m["scale"] - 0.5) < 1e-12
    raw = depth_frame_metrics(gt * 1.1, gt, scale=1.0)
    assert abs(raw["abs_rel"] - 0.1) < 1e-9 and abs(raw["rmse"] - 1.0) < 1e-9
    seq = depth_sequence_metrics([gt * 2, gt * 2], [gt, gt], unscaled=True)
    assert seq["sequence_scaled"]["abs_rel"] < 1e-12 and seq["unscaled"]["abs_rel"] > 0.9


def test_holdout_rule():
    train, held = holdout_split(list(range(20)), 8)
    assert held == [0, 8, 16] and 0 not in train and len(train) == 17


# --- training -------------------------------------------------------------------------------


def test_training_lowers_the_loss_and_renders_z_depth(tmp_path):
    cfg = tiny_config(steps=100)
    frames, train, held, prior, box, k, poses, depths = tiny_setup(cfg)
    tr = Trainer(cfg, frames, train, prior, box, tmp_path, log=lambda m: None)
    tr.fit()
    photo = [r["photo"] for r in tr.rows]
    assert np.mean(photo[-3:]) < 0.5 * np.mean(photo[:3])
    tr.write_log(tmp_path / "train_log.csv")
    assert (tmp_path / "train_log.csv").read_text().startswith("step,loss")
    save_model(tmp_path / "model.pt", tr.model)
    model = load_model(tmp_path)
    out = render_image(model, prior, k, poses[held[0]])
    assert out["depth"].shape == (H, W) and out["depth"].dtype == np.float32
    assert out["rgb"].shape == (H, W, 3) and out["opacity"].shape == (H, W)
    gt = depths[held[0]]
    ok = out["depth"] > 0
    assert ok.mean() > 0.9
    # World units, z-depth: unscaled, the rendering is already close to the truth.
    ratio = np.median(out["depth"][ok] / gt[ok])
    assert 0.7 < ratio < 1.4, ratio
    grid = density_grid(model, resolution=24)
    assert grid.values.ndim == 3 and max(grid.values.shape) == 24
    assert np.isfinite(grid.values).all() and grid.values.max() > 0


def test_photo_weight_scales_l_photo_alone(tmp_path):
    """nerf.loss.photo_weight multiplies L_photo and nothing else: from one seed the first step
    sees the same batch, so the loss differs by exactly (w - 1) x L_photo."""
    rows = []
    for w in (1.0, 3.0):
        cfg = tiny_config(steps=1)
        cfg.loss.photo_weight = w
        frames, train, _, prior, box, *_ = tiny_setup(cfg)
        tr = Trainer(cfg, frames, train, prior, box, tmp_path / str(w), log=lambda m: None)
        tr.fit()
        rows.append(tr.rows[0])
    assert rows[0]["photo"] == pytest.approx(rows[1]["photo"], rel=1e-6) and rows[0]["photo"] > 0
    assert rows[1]["loss"] - rows[0]["loss"] == pytest.approx(2 * rows[0]["photo"], rel=1e-4)


def test_checkpoint_resume_continues_and_matches(tmp_path):
    cfg = tiny_config(steps=40, checkpoint_every=20)
    setup = tiny_setup(cfg)
    frames, train, _, prior, box = setup[:5]
    ref = Trainer(cfg, frames, train, prior, box, tmp_path / "a", log=lambda m: None)
    ref.fit()
    (tmp_path / "b").mkdir()
    first = Trainer(cfg, frames, train, prior, box, tmp_path / "b", log=lambda m: None)
    for _ in range(20):
        first.step()
    first.save_checkpoint()  # ... then the process is killed
    again = Trainer(cfg, frames, train, prior, box, tmp_path / "b", log=lambda m: None)
    assert again.try_resume() and again.step_i == 20
    again.fit()
    assert again.step_i == 40
    for (name, a), b in zip(
        ref.model.state_dict().items(), again.model.state_dict().values(), strict=True
    ):
        assert torch.allclose(a, b, atol=1e-4, rtol=1e-3), name


def test_scene_box_warp_is_monotonic_and_identity_in_core():
    box = SceneBox(
        np.zeros(3), np.eye(3), 1.0, -np.ones(3) * 8, np.ones(3) * 8, -np.ones(3), np.ones(3)
    )
    x = torch.linspace(-8, 8, 201)[:, None].expand(-1, 3).contiguous()
    g = box.to_grid(x)[:, 0]
    assert (g[1:] > g[:-1]).all() and abs(g[0] + 1) < 1e-5 and abs(g[-1] - 1) < 1e-5
    core = x[:, 0].abs() <= 1
    slope = (g[core][1:] - g[core][:-1]) / (x[core, 0][1:] - x[core, 0][:-1])
    assert torch.allclose(slope, slope[0].expand_as(slope), rtol=1e-3)
    k = Camera(width=11, height=11, fx=10.0, fy=10.0, cx=5.0, cy=5.0)
    o, d = pixel_rays(k, torch.eye(4), torch.tensor([5.0]), torch.tensor([5.0]))
    assert torch.allclose(d, torch.tensor([[0.0, 0.0, 1.0]]))


def test_grid_warp_auto_follows_where_the_sfm_points_lie():
    """The warp spends the grid near the camera path: kept when the SfM points lie there, off
    when they lie far down the tube (C3VD: 14% near its short path; warped, it lost detail)."""
    k, poses, prior = intrinsics(), tube_poses(10), tube_prior()
    theta = np.linspace(0, 2 * np.pi, 40)

    def wall(z0: float, z1: float) -> np.ndarray:
        t, z = np.meshgrid(theta, np.linspace(z0, z1, 10))
        return np.stack([RADIUS * np.cos(t), RADIUS * np.sin(t), z], -1).reshape(-1, 3)

    cfg = tiny_config()
    assert cfg.field.warp == "auto"
    assert fit_box(poses, k, (H, W), prior, cfg, wall(2, 13)).warped
    assert not fit_box(poses, k, (H, W), prior, cfg, wall(40, 60)).warped
    assert fit_box(poses, k, (H, W), prior, cfg).warped  # no SfM points: the warp stays
    far = regularise_far_view(cfg, fit_box(poses, k, (H, W), prior, cfg, wall(40, 60)), print)
    assert far.field.tensorf.tv_weight == cfg.far_view.tv_weight > 0
    assert far.loss.distortion_weight == cfg.far_view.distortion_weight > 0
    assert far.field.tensorf.res_final == min(40, cfg.far_view.res_final or 40)
    near = regularise_far_view(cfg, fit_box(poses, k, (H, W), prior, cfg, wall(2, 13)), print)
    assert near.field.tensorf.tv_weight == 0 and near.loss.distortion_weight == 0
    cfg.far_view.res_final = 32  # a coarser unwarped grid; never under res_init (24)
    far = regularise_far_view(cfg, fit_box(poses, k, (H, W), prior, cfg, wall(40, 60)), print)
    assert far.field.tensorf.res_final == 32
    cfg.far_view.res_final = 16
    far = regularise_far_view(cfg, fit_box(poses, k, (H, W), prior, cfg, wall(40, 60)), print)
    assert far.field.tensorf.res_final == 24
    near = regularise_far_view(cfg, fit_box(poses, k, (H, W), prior, cfg, wall(2, 13)), print)
    assert near.field.tensorf.res_final == 40
    cfg.field.warp = True
    assert fit_box(poses, k, (H, W), prior, cfg, wall(40, 60)).warped
    cfg.field.warp = False
    assert not fit_box(poses, k, (H, W), prior, cfg, wall(2, 13)).warped


def test_a_still_cameras_grid_lies_over_its_view():
    """warp: frustum (a still camera's auto): every sample of a pixel's ray reads the same
    place of the grid's image planes, the image spans the grid's width and height, depth runs
    along the third axis; the grid maps back to the world and is saved with the model's box."""
    k, prior = intrinsics(), tube_prior()
    still = [tube_poses(1)[0]] * 5
    cfg = tiny_config()
    cfg.field.warp = "frustum"
    box = fit_box(still, k, (H, W), prior, cfg)
    assert box.frustum is not None and not box.warped
    c2w = torch.tensor(box.c2w_to_scene(still[0]), dtype=torch.float32)
    u = torch.tensor([0.0, 1.0, W / 2, W - 1.0])
    v = torch.tensor([0.0, 0.0, H / 2, H - 1.0])
    o, d = pixel_rays(k, c2w, u, v)
    t = torch.linspace(0.5, 5.0, 7)
    g = box.to_grid((o[:, None] + t[None, :, None] * d[:, None]).reshape(-1, 3)).view(4, 7, 3)
    assert torch.allclose(g[..., :2], g[:, :1, :2].expand(-1, 7, -1), atol=1e-5)
    assert (g[..., 2].diff(dim=1) > 0).all()  # depth along the grid's third axis
    assert (g.abs() <= 1).all()  # the view's corners inside, with their margin
    # the image spans the grid's width but for the 5% margins: its planes lie on the pixels
    assert 0.85 < float(g[3, 0, 0] - g[0, 0, 0]) / 2 < 0.95
    assert 0.85 < float(g[3, 0, 1] - g[0, 0, 1]) / 2 < 0.95
    back = box.grid_to_world_np(g.reshape(-1, 3).numpy().astype(np.float64))
    world = box.scene_to_world_np((o[:, None] + t[None, :, None] * d[:, None]).reshape(-1, 3))
    assert np.allclose(back, world, atol=1e-4)
    behind = box.to_grid(o[:1] - d[:1])  # behind the camera: outside the grid
    assert (behind.abs() > 1).any()
    # depth has its share of the image's nodes; a state without `depth_nodes` reads as a
    # share of one, the grid's shape it was saved with
    span = box.frustum.hi - box.frustum.lo
    assert np.isclose(box.extent[2], cfg.field.frustum_depth_nodes * span[:2].max())
    again = SceneBox.from_state(box.state())
    assert again.frustum is not None and np.allclose(again.extent, box.extent)
    old = box.state()
    del old["frustum"]["depth_nodes"]
    assert np.isclose(SceneBox.from_state(old).extent[2], span[:2].max())


def test_paper_preset_trains_with_coarse_and_fine_passes(tmp_path):
    from endopipe.pipeline.config import deep_merge, read_yaml, resolve_config_path

    paper = read_yaml(resolve_config_path("paper"))["nerf"]  # the preset a user names
    raw = deep_merge(paper, {"field": {"positional": {"width": 32}}})
    cfg = NerfConfig.model_validate(raw)
    assert cfg.field.encoding == "positional" and cfg.sampling.n_fine == 128
    assert cfg.train.steps == 200000 and cfg.train.time_budget_s is None
    assert cfg.train.still_steps == 1.0  # the seed trains a still camera as any other
    cfg.sampling.n_coarse, cfg.sampling.n_fine = 16, 16
    cfg.train.steps, cfg.train.batch_rays = 3, 64
    frames, train, held, prior, box, k, poses, _ = tiny_setup(cfg, n_frames=4)
    tr = Trainer(cfg, frames, train, prior, box, tmp_path, log=lambda m: None)
    tr.fit()
    assert tr.step_i == 3 and np.isfinite(tr.rows[-1]["loss"])
    out = render_image(tr.model.eval(), prior, k, poses[0], colour=True)
    assert out["depth"].shape == (H, W) and np.isfinite(out["rgb"]).all()


# --- the stage in the pipeline, killed and resumed -------------------------------------------


def write_case(folder: Path, n: int = 10) -> None:
    k = intrinsics()
    (folder / "frames").mkdir(parents=True)
    (folder / "gt" / "depth").mkdir(parents=True)
    poses = tube_poses(n)
    for i, p in enumerate(poses):
        rgb, depth = tube_frame(k, p)
        cv2.imwrite(str(folder / "frames" / f"{i:06d}.png"), rgb[:, :, ::-1])
        np.save(folder / "gt" / "depth" / f"{i:06d}.npy", depth)
    (folder / "intrinsics.json").write_text(json.dumps(k.model_dump(exclude={"dist"})))
    (folder / "gt" / "poses.json").write_text(
        json.dumps(
            {"convention": "opencv_c2w", "units": "mm", "poses": [p.tolist() for p in poses]}
        )
    )


def test_stage_resumes_after_a_kill(tmp_path, monkeypatch):
    from endopipe.cli import prepare_case
    from endopipe.pipeline.config import load_config
    from endopipe.pipeline.runner import Pipeline
    from endopipe.pipeline.stage import Stage, Summary
    from endopipe.stages.centerline.view import CenterlineView
    from endopipe.stages.ingest.stage import Ingest
    from endopipe.stages.nerf import train as train_mod
    from endopipe.stages.nerf.stage import Nerf
    from endopipe.stages.poses.stage import Poses

    class PriorOnly(CenterlineView):
        """The stand-in's folder: prior.npz and nothing else."""

        def __init__(self, folder: Path) -> None:
            self.folder = Path(folder)

    class Centerline(Stage):
        """Test stand-in: the known tube as prior.npz."""

        name = "centerline"
        needs = ("poses",)
        View = PriorOnly

        def run(self, ctx):
            save_prior(tube_prior(), ctx.out / "prior.npz")
            return Summary()

    write_case(tmp_path / "case")
    stages = [Ingest, Poses, Centerline, Nerf]
    sets = [
        "poses.source=gt",
        "ingest.drop_duplicates=false",
        "ingest.drop_blurred=false",
        "nerf.field.tensorf.res_init=24",
        "nerf.field.tensorf.res_final=40",
        "nerf.sampling.n_coarse=32",
        "nerf.sampling.n_fine=16",
        "nerf.train.batch_rays=256",
        "nerf.train.steps=30",
        "nerf.train.checkpoint_every=10",
        "nerf.train.time_budget_s=null",
    ]
    configs = load_config(stages, sets=sets, use_default_file=False)
    case_dir = prepare_case(tmp_path / "case", tmp_path / "work", None, None)
    pipe = Pipeline(stages)

    real_step = train_mod.Trainer.step

    def dying_step(self):
        if self.step_i == 25:
            raise KeyboardInterrupt("killed")
        return real_step(self)

    monkeypatch.setattr(train_mod.Trainer, "step", dying_step)
    with pytest.raises(KeyboardInterrupt):
        pipe.run(case_dir, configs, quiet=True)
    assert list(case_dir.glob(".04_nerf.tmp-*/checkpoint.pt"))
    monkeypatch.setattr(train_mod.Trainer, "step", real_step)
    record = pipe.run(case_dir, configs, quiet=True)
    summary = record.stages[-1].summary
    assert summary["resumed_from"] == 20 and summary["steps"] == 30
    out = case_dir / "04_nerf"
    for name in ("model.pt", "train_log.csv", "loss.png", "metrics.json", "heldout.png"):
        assert (out / name).is_file(), name
    assert not (out / "checkpoint.pt").exists()
    assert summary["depth"]["median_scaled"]["abs_rel"] < 1.0
    rows = (out / "train_log.csv").read_text().splitlines()
    assert rows[-1].startswith("30,")
    assert not summary["budget_stopped"] and summary["planned_steps"] == 30
    # the held-out renders are kept for the depth stage (PSNR / SSIM without a second render)
    view = Nerf.view(out)
    assert view.heldout and all(view.heldout_rgb(i).shape == (H, W, 3) for i in view.heldout)

    # The time budget ends training only past it, and says at which step.
    budget = [*sets, "nerf.train.steps=100000", "nerf.train.time_budget_s=1"]
    configs = load_config(stages, sets=budget, use_default_file=False)
    record = pipe.run(case_dir, configs, quiet=True)
    summary = record.stages[-1].summary
    assert summary["budget_stopped"] and 0 < summary["steps"] < summary["planned_steps"], summary


# --- accuracy (slow) ---------------------------------------------------------------------------


@pytest.mark.slow
def test_synthetic_colon_accuracy(tmp_path):
    """Default config, GT poses, a 60-frame 320x256 synthetic colon: held-out depth AbsRel <=
    0.10 and delta < 1.25 >= 0.90 with per-frame median scaling."""
    from endopipe.cli import all_stages, prepare_case
    from endopipe.pipeline.config import load_config
    from endopipe.pipeline.runner import Pipeline
    from endopipe.synth import SynthConfig, generate_case

    generate_case(tmp_path / "colon", SynthConfig(frames=60, width=320, height=256))
    stages = [s for s in all_stages() if s.name in ("ingest", "poses", "centerline", "nerf")]
    configs = load_config(stages, sets=["poses.source=gt"], use_default_file=False)
    case_dir = prepare_case(tmp_path / "colon", tmp_path / "work", None, None)
    record = Pipeline(stages).run(case_dir, configs, quiet=True)
    summary = record.stages[-1].summary
    m = summary["depth"]["median_scaled"]
    assert m["abs_rel"] <= 0.10 and m["delta1"] >= 0.90, m
