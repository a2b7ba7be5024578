"""A colour channel whose albedo sat at its ceiling after training is fitted again with the
geometry fixed (stages/nerf/colour_phase.py): the channel leaves the ceiling, the renders come
closer to the images, and the density, hence the depth, is the same to the bit."""

from __future__ import annotations

from contextlib import contextmanager

import pytest
import torch

from endopipe.stages.nerf import losses
from endopipe.stages.nerf.colour_phase import refit_if_pinned
from endopipe.stages.nerf.data import RaySampler
from endopipe.stages.nerf.train import Trainer
from tests.tube_scene import (  # noqa: F401 - one_torch_thread is a fixture
    one_torch_thread,
    tiny_config,
    tiny_setup,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@contextmanager
def no_bar(description: str, total: int | None):
    yield lambda n=1, **_: None


@torch.no_grad()
def photo_error(tr: Trainer) -> float:
    """L_photo over one fixed draw of training rays, rendered as for evaluation."""
    gen = torch.Generator().manual_seed(5)
    b = RaySampler(tr.frames, tr.train_pos, 2048, 2, 0.0, gen).sample()
    o, d = tr.frames.rays(b.frame, b.u, b.v)
    near, far = tr.ray_bounds(o, d, b)
    tr.model.eval()
    out = tr.model.render_rays(o, d, near, far, frame=b.frame, colour=True)
    tr.model.train()
    return float(losses.photo(out["rgb"], b.rgb, b.valid))


def red_scene(tr_cfg):
    """The tube's frames tinted as a red scope's (C3VD: red 0.7, green 0.3, blue 0.2 at the
    median) and a light started too dim for the red: red ends training all shading."""
    frames, train, _, prior, box, *_ = tiny_setup(tr_cfg)
    frames.images = (frames.images * torch.tensor((2.0, 0.8, 0.5))).clamp(0, 1)
    return frames, train, prior, box


def test_a_grey_scene_leaves_the_albedo_as_trained(tmp_path) -> None:
    cfg = tiny_config(steps=80, colour_steps=80)
    frames, train, _, prior, box, *_ = tiny_setup(cfg)
    tr = Trainer(cfg, frames, train, prior, box, tmp_path, log=lambda m: None)
    tr.fit()
    refit = refit_if_pinned(tr, print, no_bar)
    assert refit is not None and refit.steps == 0 and max(refit.ceiling) < 0.05


def test_a_pinned_channel_is_fitted_again_and_the_geometry_stays(tmp_path) -> None:
    """Measured: red at its ceiling on 54% of the rays, its pixels asking 4.4 times it; after
    80 steps on 22%, and L_photo 0.0011 from 0.0384."""
    cfg = tiny_config(steps=80, colour_steps=80, colour_ceiling=0.4)
    frames, train, prior, box = red_scene(cfg)
    tr = Trainer(cfg, frames, train, prior, box, tmp_path, log=lambda m: None)
    with torch.no_grad():
        tr.model.log_gain -= 1.5
    tr.fit()
    before = photo_error(tr)
    density = [p.detach().clone() for p in tr.model.field.density_grid.parameters()]
    lines: list[str] = []
    refit = refit_if_pinned(tr, lines.append, no_bar)
    assert refit is not None and refit.steps == 80 and refit.ceiling[0] > 0.4
    assert refit.asked is not None and refit.asked[0] > 2 and "red channel" in lines[0]
    assert refit.ceiling_after is not None and refit.ceiling_after[0] < 0.3
    after = photo_error(tr)
    assert after < 0.1 * before, (before, after)
    for old, new in zip(density, tr.model.field.density_grid.parameters(), strict=True):
        assert torch.equal(old, new)  # the geometry, hence the depth, the same to the bit
    assert tr.step_i == 80 and all(p.requires_grad for p in tr.model.field.parameters())
