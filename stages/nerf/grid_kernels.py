"""Compiled loops (numba) for the VM grids on a CPU: the tables' gradient, and a read that needs
no gradient.

The gradient: each point's weighted corners added into the table's rows, with no sort.

Why: on a CPU, torch's `index_add_` runs as a scatter that sorts its indices first, a sort per
corner and per table read, and that scatter was the largest single cost of a training step (a
quarter to a third of it: `scripts/bench_nerf_step.py --profile`). The loop here reads the points
in order and adds each corner's weighted gradient row into the table. Threads split the table's
rows, each thread adding only into its own share, so a row's sum is taken in the points' order
whatever the number of threads: the result does not depend on the thread count or the load.

The read without a gradient (a frame rendered, the refit's pool, the proposal grid's refresh):
each point's plane and line interpolated and multiplied in one pass over the points, instead of
torch's index and weight tensors (four a corner set, 3 x N rows each), two gathers and a product.
A grid over time reads so too, each point in its lines sliced at its time.

Numba's own thread pool (`workqueue`), not a second OpenMP runtime beside torch's.
"""

from __future__ import annotations

import numba
import numpy as np
import torch
from numba import njit, prange

numba.config.THREADING_LAYER = "workqueue"

#: The VM grid's plane / line pairs, (plane axes a, b | line axis c): (x, y | z), (x, z | y),
#: (y, z | x). The read's loop is written for these (VMGrid.PAIRS is this).
VM_PAIRS = ((0, 1, 2), (0, 2, 1), (1, 2, 0))


def use_torch_threads() -> int:
    """Numba's threads for the next loop: torch's count (the stage's setting), at most numba's."""
    threads = max(1, min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS))
    numba.set_num_threads(threads)
    return threads


@njit(parallel=True, cache=True, nogil=True)
def _add_corners(
    g: np.ndarray, idx: np.ndarray, w: np.ndarray, grad: np.ndarray, parts: int
) -> None:  # pragma: no cover - compiled
    rows, channels = g.shape
    n, k = idx.shape
    for part in prange(parts):
        lo = rows * part // parts
        hi = rows * (part + 1) // parts
        for i in range(n):
            for j in range(k):
                r = idx[i, j]
                if r >= lo and r < hi:
                    wj = w[i, j]
                    for c in range(channels):
                        g[r, c] += wj * grad[i, c]


def add_weighted_corners(
    g: torch.Tensor, idx: torch.Tensor, w: torch.Tensor, grad: torch.Tensor
) -> None:
    """g[idx[n, k]] += w[n, k] * grad[n] for every point n and corner k, in place. `g` (R, C),
    `idx` (N, K) int64, `w` (N, K), `grad` (N, C), all on the CPU and of one float dtype."""
    if idx.numel() == 0:
        return
    assert g.is_contiguous() and g.device.type == "cpu", "a contiguous CPU table"
    threads = use_torch_threads()
    _add_corners(
        g.detach().numpy(),
        idx.contiguous().numpy(),
        w.detach().contiguous().numpy(),
        grad.detach().contiguous().numpy(),
        threads,
    )


@njit(inline="always")
def _cell(x: float, r: int) -> tuple:  # pragma: no cover - compiled
    """A coordinate in [-1, 1] on an axis of r nodes: (lower node, fraction), as `prepare`."""
    q = (x + np.float32(1.0)) * np.float32(np.float32(0.5) * np.float32(r - 1))
    q = min(max(q, np.float32(0.0)), np.float32(r - 1))
    c = min(np.floor(q), np.float32(r - 2))
    return np.int64(c), np.float32(q - c)


@njit(parallel=True, cache=True, nogil=True)
def _vm_read(
    x: np.ndarray,
    planes: np.ndarray,
    lines: np.ndarray,
    res: np.ndarray,
    poff: np.ndarray,
    loff: np.ndarray,
    lshift: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    one, zero = np.float32(1.0), np.float32(0.0)
    channels = planes.shape[1]
    shifted = lshift.shape[0] > 0
    for i in prange(x.shape[0]):
        shift = lshift[i] if shifted else 0
        c0, f0 = _cell(x[i, 0], res[0])
        c1, f1 = _cell(x[i, 1], res[1])
        c2, f2 = _cell(x[i, 2], res[2])
        for p in range(3):  # VM_PAIRS: (x, y | z), (x, z | y), (y, z | x)
            if p == 0:
                ca, fa, cb, fb, cc, fc, ra = c0, f0, c1, f1, c2, f2, res[0]
            elif p == 1:
                ca, fa, cb, fb, cc, fc, ra = c0, f0, c2, f2, c1, f1, res[0]
            else:
                ca, fa, cb, fb, cc, fc, ra = c1, f1, c2, f2, c0, f0, res[1]
            ga, gb = one - fa, one - fb
            w0, w1, w2, w3 = ga * gb, fa * gb, ga * fb, fa * fb
            r0 = poff[p] + cb * ra + ca
            l0 = loff[p] + cc + shift
            lw0 = one - fc
            for ch in range(channels):
                plane = zero
                plane += w0 * planes[r0, ch]
                plane += w1 * planes[r0 + 1, ch]
                plane += w2 * planes[r0 + ra, ch]
                plane += w3 * planes[r0 + ra + 1, ch]
                line = zero
                line += lw0 * lines[l0, ch]
                line += fc * lines[l0 + 1, ch]
                out[i, p * channels + ch] = plane * line


def reads_fused(x: torch.Tensor, *tables: torch.Tensor) -> bool:
    """Whether `vm_read` serves this read: float32 on a CPU, and no gradient wanted."""
    if x.device.type != "cpu" or x.dtype != torch.float32:
        return False
    if any(t.dtype != torch.float32 or t.device.type != "cpu" for t in tables):
        return False
    wanted = x.requires_grad or any(t.requires_grad for t in tables)
    return not (torch.is_grad_enabled() and wanted)


def vm_read(
    x: torch.Tensor,
    planes: torch.Tensor,
    lines: torch.Tensor,
    res: torch.Tensor,
    poff: torch.Tensor,
    loff: torch.Tensor,
    lshift: torch.Tensor | None = None,
) -> torch.Tensor:
    """VMGrid's forward (N, 3 C) for points x (N, 3) in [-1, 1]^3 (beyond: at the border), the
    same sums as its gathers in the same order (to 1e-8: a gather's rounding), without their
    set-up. `res`, `poff`, `loff`: the grid's nodes an axis and its planes' and lines' first
    rows, a pair each (int64, VM_PAIRS' order: VMGrid's cached constants). `lshift` (N,)
    int64: each point's lines start that many rows further (a grid over time's lines sliced
    at several times, one slice after the other)."""
    n, channels = x.shape[0], planes.shape[1]
    out = torch.empty(n, 3 * channels, dtype=torch.float32)
    if n == 0:
        return out
    use_torch_threads()
    _vm_read(
        x.detach().contiguous().numpy(),
        planes.detach().contiguous().numpy(),
        lines.detach().contiguous().numpy(),
        res.numpy(),
        poff.numpy(),
        loff.numpy(),
        np.zeros(0, np.int64) if lshift is None else lshift.contiguous().numpy(),
        out.numpy(),
    )
    return out
