"""The grid tables' gradient on a CPU: each point's weighted corners added into the table's rows
by a compiled loop (numba), with no sort.

Why: on a CPU, torch's `index_add_` runs as a scatter that sorts its indices first, a sort per
corner and per table read, and that scatter was the largest single cost of a training step (a
quarter to a third of it: `scripts/bench_nerf_step.py --profile`). The loop here reads the points
in order and adds each corner's weighted gradient row into the table. Threads split the table's
rows, each thread adding only into its own share, so a row's sum is taken in the points' order
whatever the number of threads: the result does not depend on the thread count or the load.
Numba's own thread pool (`workqueue`), not a second OpenMP runtime beside torch's.
"""

from __future__ import annotations

import numba
import numpy as np
import torch
from numba import njit, prange

numba.config.THREADING_LAYER = "workqueue"


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
    threads = max(1, min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS))
    numba.set_num_threads(threads)
    _add_corners(
        g.detach().numpy(),
        idx.contiguous().numpy(),
        w.detach().contiguous().numpy(),
        grad.detach().contiguous().numpy(),
        threads,
    )
