"""A breathing lumen (`nerf.field.breathing`): the field is one canonical lumen, and a point seen
at time t is read at its foot on the centre curve plus its offset scaled by exp(-g(place, t)):
a wall that is wider at one time is read as the canonical wall."""

from __future__ import annotations

import math

import numpy as np
import torch

from endopipe.stages.nerf.breathing import LumenBreathing
from endopipe.stages.nerf.encodings import VMGrid
from endopipe.stages.nerf.render import load_model, save_model
from endopipe.stages.nerf.train import Trainer
from tests.tube_scene import tiny_config, tiny_setup


def straight_curve() -> torch.Tensor:
    z = torch.linspace(-5.0, 65.0, 30)
    return torch.stack([torch.zeros_like(z), torch.zeros_like(z), z], 1)


def test_a_point_is_read_at_its_canonical_radius_for_its_time() -> None:
    breathing = LumenBreathing(straight_curve(), knots=2, times=3)
    with torch.no_grad():
        # the wall 10% wider than its mean at the last time, as wide at the first and middle
        breathing.table.copy_(torch.tensor([[0.0, 0.0, math.log(1.1)]] * 2))
    g = breathing.centred()
    assert torch.allclose(g.mean(1), torch.zeros(2), atol=1e-7)  # the canonical is the mean
    x = torch.tensor([[3.0, 4.0, 20.0], [3.0, 4.0, 20.0], [0.0, 6.0, 40.0]])
    t = torch.tensor([1.0, -1.0, 0.0])
    got = breathing.canonical(x, t)
    scale = torch.exp(-torch.stack([g[0, 2], g[0, 0], g[0, 1]]))
    want = x.clone()
    want[:, :2] *= scale[:, None]
    assert torch.allclose(got, want, atol=1e-5)
    assert got[0, :2].norm() < 5.0 < got[1, :2].norm()  # wider at t = 1: read nearer the axis
    assert abs(breathing.amplitude() - (1.1 ** (2 / 3) - 1)) < 1e-5


def test_the_grid_gives_its_points_gradients_only_when_asked() -> None:
    g = VMGrid((9, 7, 13), 3).double()
    x = (torch.rand(40, 3, dtype=torch.float64) * 1.8 - 0.9).requires_grad_()

    def value(p: torch.Tensor) -> torch.Tensor:
        return g(p, g.prepare(p, positional=True)).sum(-1)

    # the trilinear value's derivative inside each cell, against central differences
    assert torch.autograd.gradcheck(value, (x,), eps=1e-7, atol=1e-5)
    plain = g(x, g.prepare(x)).sum()
    assert not plain.requires_grad or torch.autograd.grad(plain, x, allow_unused=True)[0] is None


def test_a_breathing_model_trains_saves_and_loads_its_curve_and_table(tmp_path) -> None:
    torch.set_num_threads(1)
    cfg = tiny_config(steps=20)
    cfg.field.breathing = True
    cfg.field.time_nodes = 4
    frames, train, _, prior, box, *_ = tiny_setup(cfg, n_frames=6)
    from endopipe.stages.nerf.train import breathing_curve

    curve = breathing_curve(prior, box)
    tr = Trainer(cfg, frames, train, prior, box, tmp_path, log=lambda m: None)
    tr.model.set_frame_times(list(range(frames.n)))
    tr.fit()
    assert tr.model.breathing is not None and tr.model.moves
    assert float(tr.model.breathing.table.detach().abs().max()) > 0  # it is trained
    save_model(tmp_path / "model.pt", tr.model, {"frame_ids": list(range(frames.n))})
    loaded = load_model(tmp_path / "model.pt")
    assert torch.equal(loaded.breathing.curve, curve)
    assert torch.equal(loaded.breathing.table, tr.model.breathing.table.detach())
    x = torch.as_tensor(np.array([[0.05, 0.02, 0.1]] * 4), dtype=torch.float32)
    with loaded.at_frame(5), torch.no_grad():
        a = loaded.density_scene(x)
    with tr.model.at_frame(5), torch.no_grad():
        b = tr.model.eval().density_scene(x)
    assert torch.allclose(a, b)
