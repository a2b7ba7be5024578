"""Joint pose refinement (nerf/pose_refine.py): exact when nothing is learnt, one convention from
scene to world, the gauge, the artefact downstream stages read, and recovery of perturbed poses.

Uses the analytic tube scene of test_nerf.py (exact images and poses)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from endopipe.stages.camera import Camera
from endopipe.stages.nerf.data import FrameSet, holdout_split
from endopipe.stages.nerf.pose_refine import (
    PoseCorrection,
    corrected_world,
    movement,
    path_length,
    record,
    refinement_wanted,
)
from endopipe.stages.nerf.render import load_model, save_model
from endopipe.stages.nerf.scene import SceneBox
from endopipe.stages.nerf.stage import fit_box
from endopipe.stages.nerf.train import Trainer
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import CamerasFile, PosesView
from tests.test_nerf import tiny_config, tiny_setup, tube_frame, tube_poses, tube_prior


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def test_auto_refines_sfm_poses_only():
    assert refinement_wanted("auto", "colmap")
    assert not refinement_wanted("auto", "gt") and not refinement_wanted("auto", "file")
    assert refinement_wanted("on", "gt") and not refinement_wanted("off", "colmap")


def test_scene_and_world_corrections_are_one_convention():
    """The torch correction in the scene frame, mapped back to the world, equals
    corrected_world on the world poses; zero corrections give the poses back bit for bit."""
    rot = Rotation.from_euler("xyz", [20, -35, 50], degrees=True).as_matrix()
    box = SceneBox([3.0, -1.0, 7.0], rot, 4.0, -np.ones(3), np.ones(3))
    poses = tube_poses(4)
    scene = torch.tensor(np.stack([box.c2w_to_scene(p) for p in poses]), dtype=torch.float64)
    corr = PoseCorrection(4).double()
    same = corrected_world(poses, np.zeros((4, 6)), box)
    assert all(np.array_equal(a, b) for a, b in zip(same, poses, strict=True))
    assert torch.equal(corr.apply(scene), scene)
    with torch.no_grad():
        corr.delta.copy_(torch.tensor(np.random.default_rng(1).normal(0, 0.05, (4, 6))))
    got = corrected_world(poses, corr.effective().detach().numpy(), box)
    for s, w in zip(corr.apply(scene).detach().numpy(), got, strict=True):
        back = np.eye(4)
        back[:3, :3] = rot @ s[:3, :3]
        back[:3, 3] = box.scene_to_world_np(s[:3, 3])
        np.testing.assert_allclose(back, w, atol=1e-9)


def test_gauge_frames_are_corrected_relative_to_their_mean():
    """Moving every training camera the same way is no correction (the rigid gauge); held-out
    frames (outside the gauge) keep theirs."""
    corr = PoseCorrection(5, gauge=[1, 2, 3, 4])
    with torch.no_grad():
        corr.delta[:] = torch.tensor([0.01, -0.02, 0.03, 0.1, 0.2, -0.3])
    eff = corr.effective().detach()
    assert eff[1:].abs().max() < 1e-7
    assert torch.equal(eff[0], corr.delta.detach()[0])


def _train(cfg, refine: bool, tmp_path, name: str):
    frames, train, held, prior, box = tiny_setup(cfg)[:5]
    tr = Trainer(cfg, frames, train, prior, box, tmp_path / name, lambda m: None, None, refine)
    tr.fit()
    return tr, held


def test_refinement_with_nothing_learnt_is_the_unrefined_path(tmp_path):
    """mode on with a zero learning rate trains exactly the model of mode off, casting the same
    rays from the first step; with a learning rate the poses and the field change."""
    cfg = tiny_config(steps=12)
    cfg.pose_refine.start = 0.0
    cfg.pose_refine.warmup = 0.0
    off, _ = _train(cfg, False, tmp_path, "off")
    cfg.pose_refine.lr = 0.0
    zero, held = _train(cfg, True, tmp_path, "zero")
    assert zero.refine_heldout([zero.frames.ids.index(i) for i in held])
    for (name, a), b in zip(
        off.model.state_dict().items(), zero.model.state_dict().values(), strict=True
    ):
        assert torch.equal(a, b), name
    poses = tube_poses(10)
    assert all(np.array_equal(a, b) for a, b in zip(zero.world_poses(poses), poses, strict=True))
    cfg.pose_refine.lr = 1e-3
    moved, _ = _train(cfg, True, tmp_path, "moved")
    assert moved.correction is not None and moved.correction.delta.abs().max() > 1e-4
    assert not torch.equal(off.model.state_dict()["log_gain"], moved.model.state_dict()["log_gain"])


def _poses_folder(folder, poses: list[np.ndarray], k: Camera) -> PosesView:
    folder.mkdir()
    cams = CamerasFile.build(k, dict(enumerate(poses)), len(poses), metric=True, source="colmap")
    (folder / "cameras.json").write_text(cams.model_dump_json())
    return PosesView(folder)


def test_old_model_loads_and_downstream_falls_back_to_the_given_poses(tmp_path):
    """An old 04_nerf (model.pt without pose meta, no cameras_refined.json) loads and gives
    cameras.json's poses; a refined one gives the refined poses to depth and mesh."""
    cfg = tiny_config(steps=1)
    frames, train, held, prior, box, k, poses, _ = tiny_setup(cfg)
    tr = Trainer(cfg, frames, train, prior, box, tmp_path / "t", lambda m: None)
    nerf_dir = tmp_path / "04_nerf"
    nerf_dir.mkdir()
    save_model(nerf_dir / "model.pt", tr.model, {"frame_ids": list(range(10))})
    blob = torch.load(nerf_dir / "model.pt", weights_only=False)
    del blob["config"]["pose_refine"]
    torch.save(blob, nerf_dir / "model.pt")  # as written before pose refinement existed
    assert "pose_refine" not in torch.load(nerf_dir / "model.pt", weights_only=False)["config"]
    model = load_model(nerf_dir)
    assert model.cfg.pose_refine.mode == "off"  # the default
    view = NerfView(nerf_dir)
    pv = _poses_folder(tmp_path / "02_poses", poses, k)
    c2w = view.c2w(pv)
    assert sorted(c2w) == pv.registered
    assert all(np.array_equal(c2w[i], pv.c2w[i]) for i in pv.registered)

    shifted = [p.copy() for p in poses]
    shifted[3][:3, 3] += [0.5, 0.0, 0.0]
    summary = record(nerf_dir, list(range(10)), held, poses, shifted, True, False)
    assert summary["ran"] and summary["max_translation"] == pytest.approx(0.5)
    assert summary["max_translation_pct"] == pytest.approx(50 / path_length(poses))
    got = NerfView(nerf_dir).c2w(pv)
    np.testing.assert_array_equal(got[3], shifted[3])
    np.testing.assert_array_equal(got[4], poses[4])


def _perturbed(poses: list[np.ndarray], frames: list[int], deg: float, pct: float):
    """Poses with frames turned by `deg` about a random axis and moved by `pct` % of the path."""
    rng = np.random.default_rng(0)
    length = path_length(poses)
    out = [p.copy() for p in poses]
    for i in frames:
        axis, move = rng.normal(size=3), rng.normal(size=3)
        out[i][:3, :3] = (
            out[i][:3, :3]
            @ Rotation.from_rotvec(np.radians(deg) * axis / np.linalg.norm(axis)).as_matrix()
        )
        out[i][:3, 3] += pct / 100 * length * move / np.linalg.norm(move)
    return out


@pytest.mark.slow  # 26 s for a known shortfall: run with -m slow when working on refinement
@pytest.mark.xfail(
    strict=True,
    reason="not reached yet on the tube scene: perturbed frames stay near 1 deg / 2 %, and the "
    "path's end frames drift",
)
def test_refinement_moves_perturbed_poses_towards_the_truth(tmp_path):
    """Three training frames off by 1 degree and 2 % of the path: after a short joint training
    their poses are at least 40 % closer to the truth (rotation and translation)."""
    w, h = 128, 96
    f = 0.5 * w / np.tan(np.radians(45))
    k = Camera(width=w, height=h, fx=f, fy=f, cx=(w - 1) / 2, cy=(h - 1) / 2)
    truth = tube_poses(10)
    bad = [2, 5, 7]
    given = _perturbed(truth, bad, 1.0, 2.0)
    images = np.stack([tube_frame(k, p)[0] for p in truth]).astype(np.float32) / 255.0
    cfg = tiny_config(steps=400)
    cfg.pose_refine.lr = 3e-4
    prior = tube_prior()
    box = fit_box(given, k, (h, w), prior, cfg)
    scene = np.stack([box.c2w_to_scene(p) for p in given])
    masks = np.ones(images.shape[:3], bool)
    frames = FrameSet(images, masks, scene, k, list(range(10)), torch.device("cpu"))
    train, _ = holdout_split(list(range(10)), cfg.train.holdout_every)
    tr = Trainer(cfg, frames, train, prior, box, tmp_path, lambda m: None, None, True)
    tr.fit()
    refined = tr.world_poses(given)
    length = path_length(truth)
    before = movement([truth[i] for i in bad], [given[i] for i in bad], length)
    after = movement([truth[i] for i in bad], [refined[i] for i in bad], length)
    assert after["median_rotation_deg"] < 0.6 * before["median_rotation_deg"]
    assert after["median_translation"] < 0.6 * before["median_translation"]


def test_a_bare_on_off_from_the_command_line_is_a_mode() -> None:
    """`--set nerf.pose_refine.mode=on`: YAML reads on as true; the setting must still take it."""
    from endopipe.pipeline.config import parse_set
    from endopipe.stages.nerf.config import PoseRefineConfig

    assert PoseRefineConfig(mode=parse_set("nerf.pose_refine.mode=on")[1]).mode == "on"
    assert PoseRefineConfig(mode=parse_set("nerf.pose_refine.mode=off")[1]).mode == "off"
