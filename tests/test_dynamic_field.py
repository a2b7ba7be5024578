"""A field that changes with time (space-time planes): it renders each frame at its own time, so
a still camera's frames that differ (tissue that moves, light that changes) are fitted, and a
held-out frame between two trained ones comes out between them."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from endopipe.stages.nerf.data import FrameSet
from endopipe.stages.nerf.encodings import VMGrid, VMTimeGrid
from endopipe.stages.nerf.render import load_model, render_image, save_model
from endopipe.stages.nerf.train import Trainer
from tests.tube_scene import (  # noqa: F401 - one_torch_thread is a fixture
    intrinsics,
    one_torch_thread,
    tiny_config,
    tiny_setup,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_space_time_grid_starts_static_and_interpolates_its_change_in_time():
    g = VMTimeGrid((6, 7, 8), 2, times=3)
    x = torch.rand(50, 3) * 2 - 1
    static = VMGrid((6, 7, 8), 2)
    static.planes.data, static.lines.data = g.planes.data.clone(), g.lines.data.clone()
    for t in (-1.0, 0.3, 1.0):  # no change yet: the static grid at every time
        xt = torch.cat([x, torch.full((50, 1), t)], 1)
        assert torch.allclose(g(xt), static(x), atol=1e-6)
    # A change that grows with the time node: halfway between two nodes, halfway values.
    ramp = [torch.arange(3.0).repeat_interleave(g.res[c]) for *_, c in g.PAIRS]
    g.change.data = torch.cat(ramp)[:, None].expand_as(g.change).clone()
    g.planes.data.fill_(1.0)
    g.lines.data.zero_()
    mid = torch.cat([x, torch.full((50, 1), -0.5)], 1)  # between nodes 0 and 1
    assert torch.allclose(g(mid), torch.full((50, 6), 0.5), atol=1e-5)
    up = g.upsampled((9, 10, 11))
    assert torch.allclose(up(mid), torch.full((50, 6), 0.5), atol=1e-5)
    assert float(g.change_penalty().detach()) > 0


def read_with_gradients(g: VMTimeGrid, points: torch.Tensor, rows: int | None = None):
    """The grid's values at the points (the first `rows` of them) and the gradients of their
    squares' sum in its change, lines and planes; the gradients are cleared after."""
    out = g(points)[:rows]
    out.square().sum().backward()
    grads = (g.change.grad.clone(), g.lines.grad.clone(), g.planes.grad.clone())
    g.zero_grad(set_to_none=True)
    return out.detach(), grads


def test_points_at_one_time_get_the_values_and_gradients_of_the_change_corners():
    """A frame rendered at its own time reads the lines sliced there (prepare's fast path);
    its values and gradients are those of the change's (w, time) corners, which a batch at
    two times reads, point by point."""
    g = VMTimeGrid((12, 9, 10), 4, times=7)
    g.change.data.normal_(0.0, 1.0)
    x = torch.rand(300, 4) * 2 - 1
    for t in (-1.0, -0.33, 0.71, 1.0):
        x[:, 3] = t
        other = torch.tensor([[0.1, 0.2, 0.3, 0.5 if t < 0.5 else -0.5]])  # another time
        both = torch.cat([x, other])
        assert g.prepare(x)[4] is None and g.prepare(both)[4] is not None
        one, one_grads = read_with_gradients(g, x, 300)
        two, two_grads = read_with_gradients(g, both, 300)
        assert torch.allclose(one, two, atol=1e-6)
        for a, b in zip(one_grads, two_grads, strict=True):
            assert torch.allclose(a, b, atol=1e-5)


def test_points_at_a_few_times_read_the_lines_sliced_at_each_alike():
    """A batch drawn from a few frames (`frames_per_step`) reads the lines sliced at each of
    its times: the values and gradients of the change's (w, time) corners, point by point;
    more distinct times than the limit read the corners."""
    g = VMTimeGrid((12, 9, 10), 4, times=7)
    g.change.data.normal_(0.0, 1.0)
    x = torch.rand(600, 4) * 2 - 1
    x[:, 3] = torch.tensor([-1.0, -0.41, 0.2, 0.93])[torch.randint(0, 4, (600,))]
    values, grads = [], []
    for limit in (1, 4, 3):
        g.slice_up_to = limit
        assert (g.prepare(x)[4] is None) == (limit == 4)
        value, grad = read_with_gradients(g, x)
        values.append(value)
        grads.append(grad)
    assert torch.allclose(values[0], values[1], atol=1e-5)
    for a, b in zip(grads[0], grads[1], strict=True):
        assert torch.allclose(a, b, atol=1e-4)
    assert g.upsampled((13, 10, 11)).slice_up_to == 3


def test_a_batch_of_a_few_frames_draws_their_usable_pixels_alike():
    """Each batch comes from `frames_per_step` training frames, every usable pixel of theirs
    (masks honoured, patches inside the frames chosen), and over many batches from every
    training frame about as often."""
    from endopipe.stages.nerf.data import RaySampler

    k = intrinsics()
    n, h, w = 10, k.height, k.width
    masks = np.ones((n, h, w), bool)
    masks[:, :, :4] = False  # a band no ray may come from
    masks[3] = False  # a frame with no usable pixel
    images = np.random.default_rng(0).random((n, h, w, 3), dtype=np.float32)
    c2w = np.tile(np.eye(4, dtype=np.float32), (n, 1, 1))
    frames = FrameSet(images, masks, c2w, k, list(range(n)), torch.device("cpu"))
    train = [0, 1, 2, 3, 5, 6, 7, 9]
    gen = torch.Generator().manual_seed(0)
    sampler = RaySampler(frames, train, 200, 2, 0.2, gen, frames_per_step=3)
    counts = torch.zeros(n)
    for _ in range(300):
        b = sampler.sample()
        used = torch.unique(b.frame)
        assert len(used) <= 3 and set(used.tolist()) <= set(train) - {3}
        singles = slice(b.n_patches * 4, None)
        assert bool(b.valid[singles].all()) and bool((b.u[singles] >= 4).all())
        counts += torch.bincount(b.frame, minlength=n)
    share = counts[[0, 1, 2, 5, 6, 7, 9]] / counts.sum()
    assert float(share.min()) > 0.1 and float(share.max()) < 0.19, share
    assert counts[3] == 0 and counts[4] == 0 and counts[8] == 0


def still_camera_frames(cfg, n: int = 9):
    """The tube seen from one place, its colour fading from red-tinted to blue-tinted."""
    frames, _, _, prior, box, k, poses, _ = tiny_setup(cfg, n_frames=n)
    still = frames.c2w[:1].expand(n, 4, 4).cpu().numpy()
    base = frames.images[:1].cpu().numpy()
    tint = np.linspace(0.0, 1.0, n, dtype=np.float32)[:, None, None, None]
    red, blue = np.array([1.0, 0.6, 0.6], np.float32), np.array([0.6, 0.6, 1.0], np.float32)
    images = base * ((1 - tint) * red + tint * blue)
    masks = np.ones(images.shape[:3], bool)
    still_frames = FrameSet(images, masks, still, k, list(range(n)), torch.device("cpu"))
    return still_frames, prior, box, k, poses[0], images


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(-10 * np.log10(np.mean((a - b) ** 2)))


def fit(cfg, frames, prior, box, tmp_path, train, dynamic: bool):
    cfg = cfg.model_copy(deep=True)
    cfg.field.dynamic = dynamic
    cfg.field.time_nodes = 5
    cfg.loss.geo = False
    tr = Trainer(cfg, frames, train, prior, box, tmp_path, log=lambda m: None)
    tr.model.set_frame_times(list(range(frames.n)))
    tr.fit()
    return tr.model


def test_a_dynamic_field_renders_a_held_out_time_between_its_neighbours(tmp_path):
    cfg = tiny_config(steps=150)
    frames, prior, box, k, c2w, images = still_camera_frames(cfg)
    train, held = [0, 1, 3, 4, 5, 6, 8], 2  # a quarter of the way: not the average tint
    static = fit(cfg, frames, prior, box, tmp_path / "s", train, dynamic=False)
    dynamic = fit(cfg, frames, prior, box, tmp_path / "d", train, dynamic=True)
    save_model(tmp_path / "model.pt", dynamic, {"frame_ids": list(range(frames.n))})
    loaded = load_model(tmp_path / "model.pt")
    scores = {}
    for name, model in (("static", static.eval()), ("dynamic", loaded)):
        with model.at_frame(held):
            rgb = render_image(model, prior, k, c2w)["rgb"]
        scores[name] = psnr(rgb, images[held])
    # The static field can only give the average of every frame's tint; the dynamic one the
    # tint of the held-out frame's time.
    assert scores["dynamic"] > scores["static"] + 3.0, scores
    with loaded.at_frame(0):
        first = render_image(loaded, prior, k, c2w)["rgb"]
    with loaded.at_frame(8):
        last = render_image(loaded, prior, k, c2w)["rgb"]
    # red fades into blue: 0.043 and 0.034 (0.056 and 0.060 with the first pass on the field)
    assert first[..., 0].mean() > last[..., 0].mean() + 0.025
    assert last[..., 2].mean() > first[..., 2].mean() + 0.025


def test_an_albedo_over_time_fits_the_tint_and_keeps_one_geometry(tmp_path):
    """`appearance_time`: the albedo reads space-time planes, the density does not: a held-out
    frame's tint comes out of its time as the dynamic field's does, and the surface is one."""
    cfg = tiny_config(steps=150)
    frames, prior, box, k, c2w, images = still_camera_frames(cfg)
    train, held = [0, 1, 3, 4, 5, 6, 8], 2
    static = fit(cfg, frames, prior, box, tmp_path / "s", train, dynamic=False)
    timed_cfg = cfg.model_copy(deep=True)
    timed_cfg.field.appearance_time = True
    timed = fit(timed_cfg, frames, prior, box, tmp_path / "t", train, dynamic=False)
    assert timed.field.timed and not timed.field.dynamic
    save_model(tmp_path / "model.pt", timed, {"frame_ids": list(range(frames.n))})
    loaded = load_model(tmp_path / "model.pt")
    scores = {}
    for name, model in (("static", static.eval()), ("timed", loaded)):
        with model.at_frame(held):
            rgb = render_image(model, prior, k, c2w)["rgb"]
        scores[name] = psnr(rgb, images[held])
    assert scores["timed"] > scores["static"] + 3.0, scores
    x = torch.rand(500, 3) * 2 - 1
    with loaded.at_frame(0):
        first = loaded.density_scene(x)
    with loaded.at_frame(8):
        last = loaded.density_scene(x)
    assert torch.equal(first, last)  # one geometry at every time
