"""The grids' compiled loops (stages/nerf/grid_kernels.py): the tables' gradient gives the same
sums as torch's own autograd of the same interpolation, to the bit whatever the thread count; a
read without a gradient gives what the gathers give."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from endopipe.stages.nerf.encodings import FUSED_TIMES, VMGrid, VMTimeGrid, gather_interp
from endopipe.stages.nerf.grid_kernels import add_weighted_corners


def _points(n: int, rows: int, k: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    # few rows for many corners: most rows are read many times (the sums a sort path orders)
    idx = torch.randint(0, rows, (n, k), generator=g)
    return idx, torch.rand(n, k, generator=g)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_tables_gradient_is_torchs_own(dtype: torch.dtype) -> None:
    idx, w = _points(5000, 300, 4, 0)
    table = torch.randn(300, 8, dtype=dtype, requires_grad=True)
    up = torch.randn(5000, 8, dtype=dtype)
    (gather_interp(table, idx, w.to(dtype)) * up).sum().backward()
    ours = table.grad.clone()
    ref_table = table.detach().clone().requires_grad_(True)
    offsets = torch.arange(0, idx.numel(), 4)
    out = F.embedding_bag(
        idx.reshape(-1), ref_table, offsets, mode="sum", per_sample_weights=w.to(dtype).reshape(-1)
    )
    (out * up).sum().backward()
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    assert torch.allclose(ours, ref_table.grad, rtol=tol, atol=tol)
    assert ours.abs().sum() > 0


def test_the_sums_do_not_depend_on_the_thread_count() -> None:
    idx, w = _points(20000, 500, 4, 1)
    grad = torch.randn(20000, 16)
    sums = []
    before = torch.get_num_threads()
    try:
        for threads in (1, 2, 3):
            torch.set_num_threads(threads)
            g = torch.zeros(500, 16)
            add_weighted_corners(g, idx, w, grad)
            sums.append(g)
    finally:
        torch.set_num_threads(before)
    assert torch.equal(sums[0], sums[1]) and torch.equal(sums[0], sums[2])
    ref = torch.zeros(500, 16, dtype=torch.float64)
    for k in range(4):
        ref.index_add_(0, idx[:, k], (grad * w[:, k : k + 1]).double())
    assert torch.allclose(sums[0].double(), ref, atol=1e-4)


def test_a_vm_grid_trains_through_it() -> None:
    """A VM grid fitted to a smooth target through the compiled gradient gets close to it."""
    torch.manual_seed(0)
    grid = VMGrid((12, 12, 12), 4, init_std=0.1)
    opt = torch.optim.Adam(grid.parameters(), lr=0.05)
    x = torch.rand(4096, 3) * 2 - 1
    target = torch.sin(2 * x[:, :1]) * torch.cos(3 * x[:, 1:2]) + 0.5 * x[:, 2:]
    first = None
    for _ in range(150):
        opt.zero_grad()
        loss = (grid(x).sum(-1, keepdim=True) - target).square().mean()
        first = first if first is not None else loss.item()
        loss.backward()
        opt.step()
    assert loss.item() < 0.02 * first, (loss.item(), first)


def test_a_read_without_gradient_is_the_gathers_read() -> None:
    """The compiled read (no gradient wanted) gives what the gathers give, points outside the
    box included (held at its border), and the field's density through it is the same."""
    torch.manual_seed(0)
    grid = VMGrid((50, 40, 30), 8)
    x = torch.rand(20000, 3) * 2.4 - 1.2
    with torch.no_grad():
        fused = grid(x)
        gathered = grid(x, grid.prepare(x))
    assert torch.allclose(fused, gathered, atol=1e-6, rtol=1e-5)
    assert fused.abs().max() > 1e-3
    # with a gradient wanted the read goes through the gathers (and trains: above)
    assert grid.reads_fused(x) is False
    with torch.no_grad():
        assert grid.reads_fused(x) is True


def test_a_grid_over_time_reads_without_gradient_as_its_gathers_do() -> None:
    """A grid over time read with no gradient wanted (a frame rendered at its time, a training
    step's first pass at its frames' times) goes through the compiled read on its lines sliced
    at those times, and gives the gathers' read of its lines and change; points at more times
    than the slices are made for take the gathers."""
    torch.manual_seed(0)
    grid = VMTimeGrid((50, 40, 30), 8, 16)
    with torch.no_grad():
        grid.change.normal_()
    x = torch.rand(20000, 3) * 2.4 - 1.2
    one_time = torch.full((20000, 1), 0.37)
    five_times = torch.randint(0, 5, (20000, 1)).float() / 2 - 1
    many_times = torch.rand(20000, 1) * 2 - 1
    for t in (one_time, five_times, many_times):
        xt = torch.cat([x, t], 1)
        with torch.no_grad():
            assert grid.reads_fused(xt)
            read = grid(xt)
            gathered = grid(xt, grid.prepare(xt))
        assert torch.allclose(read, gathered, atol=1e-6, rtol=1e-5)
        assert read.abs().max() > 1e-2
    with torch.no_grad():  # more times than FUSED_TIMES: the gathers
        assert len(many_times.unique()) > FUSED_TIMES
        assert grid._read_sliced(torch.cat([x, many_times], 1)) is None
    assert not grid.reads_fused(xt)  # a gradient wanted: the gathers
