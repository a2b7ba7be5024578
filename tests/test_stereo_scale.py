"""The metric scale from a stereo rig's depth at the SfM points, and the field's stereo
targets: the numbers a still or moving stereo camera's millimetres rest on."""

from __future__ import annotations

import numpy as np
import torch

from endopipe.stages.nerf.stereo_depth import stereo_depth_targets
from endopipe.stages.poses.stereo_scale import MIN_POINTS, stereo_scale
from endopipe.stages.poses.view import SparseObservations

H, W, F = 48, 64, 40.0


def observations(xyz_mm: np.ndarray, c2w: dict[int, np.ndarray], unit_mm: float):
    """The points as SfM would hold them (in units of `unit_mm`), seen by every camera."""
    rows = []
    for f, pose in c2w.items():
        cam = (xyz_mm - pose[:3, 3]) @ pose[:3, :3]
        u = F * cam[:, 0] / cam[:, 2] + W / 2
        v = F * cam[:, 1] / cam[:, 2] + H / 2
        for p, uu, vv in zip(xyz_mm, u, v, strict=True):
            rows.append((f, uu, vv, *(p / unit_mm)))
    a = np.array(rows)
    n = len(a)
    return SparseObservations(
        a[:, 0].astype(np.int64), a[:, 1:3], a[:, 3:6], np.full(n, 3.0), np.zeros(n), np.ones(n)
    )


def plane_depth(z_mm: float, holes: float, seed: int) -> np.ndarray:
    """A fronto-parallel wall at z_mm with a share of unmatched (0) pixels."""
    d = np.full((H, W), z_mm, np.float32)
    d[np.random.default_rng(seed).random((H, W)) < holes] = 0.0
    return d


def test_scale_is_the_millimetres_per_sfm_unit_despite_outliers():
    rng = np.random.default_rng(0)
    xyz = np.c_[rng.uniform(-20, 20, (60, 2)), np.full(60, 50.0)]
    c2w = {0: np.eye(4), 1: np.eye(4)}
    c2w[1][:3, 3] = [2.0, 0.0, 0.0]
    obs = observations(xyz, c2w, unit_mm=8.0)
    sfm_c2w = {f: np.r_[np.c_[p[:3, :3], p[:3, 3] / 8.0], [[0, 0, 0, 1]]] for f, p in c2w.items()}
    maps = {0: plane_depth(50.0, 0.2, 1), 1: plane_depth(50.0, 0.2, 2)}
    maps[1][:, :8] = 200.0  # a band of wrong matches: the median ignores it
    found = stereo_scale(obs, sfm_c2w, maps.get, (H, W))
    assert found is not None
    assert abs(found.mm_per_unit - 8.0) < 0.08
    assert found.spread < 0.01
    assert found.points >= MIN_POINTS


def test_no_scale_without_enough_matched_points():
    xyz = np.c_[np.zeros((10, 2)), np.full(10, 50.0)]
    obs = observations(xyz, {0: np.eye(4)}, 1.0)
    assert stereo_scale(obs, {0: np.eye(4)}, lambda i: plane_depth(50.0, 0.0, 0), (H, W)) is None
    many = observations(
        np.c_[np.random.default_rng(1).uniform(-20, 20, (60, 2)), np.full(60, 50.0)],
        {0: np.eye(4)},
        1.0,
    )
    assert stereo_scale(many, {0: np.eye(4)}, lambda i: None, (H, W)) is None


class Rig:
    """The one thing the targets read of the ingest view: each frame's stereo depth."""

    def __init__(self, maps: dict[int, np.ndarray]) -> None:
        self.maps = maps

    def stereo_depth(self, i: int) -> np.ndarray | None:
        return self.maps.get(i)


def test_targets_are_matched_pixels_in_scene_units():
    maps = {0: plane_depth(40.0, 0.5, 3), 2: plane_depth(60.0, 0.5, 4)}
    targets = stereo_depth_targets(
        Rig(maps), {0: 0, 1: 1, 2: 2}, 1.0, 20.0, 100, torch.device("cpu")
    )
    assert targets is not None and len(targets) == 200
    assert set(targets.frame.tolist()) == {0, 2}  # frame 1 has no right view
    z = targets.z.numpy()
    assert np.allclose(np.sort(np.unique(z)), [2.0, 3.0])
    for f, d in maps.items():
        sel = targets.frame.numpy() == f
        rows, cols = targets.v.numpy()[sel].astype(int), targets.u.numpy()[sel].astype(int)
        assert (d[rows, cols] > 0).all()  # never an unmatched pixel
    assert stereo_depth_targets(Rig({}), {0: 0}, 1.0, 1.0, 10, torch.device("cpu")) is None
