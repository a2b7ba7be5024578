"""A coarse, conservative copy of the field's density on a dense grid over the box, read by the
first sampling pass in training instead of the field itself (nerfacc's occupancy grid, kept as
densities so that the pass still composites weights).

Why: the first pass evaluated the field at 48 points a ray with no gradients, a third of a
training step on two cores (the VM grid's 12 gathers a point). A trilinear read of a dense grid
costs a fraction of that, and the fine samples it proposes are then evaluated by the field as
before. The copy holds, per cell, the largest density seen at random points inside it, decayed
at every refresh so that density the field has since cleared fades out; a share of the cells is
refreshed every few steps, all of them when the grid's resolution changes.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F

#: Each refresh multiplies the held densities by this before taking the new maximum.
DECAY = 0.95


class ProposalGrid:
    """Densities on a (D, H, W) grid of cells over grid coordinates [-1, 1]^3 (x along W)."""

    def __init__(self, extent: tuple[float, float, float], longest: int, device) -> None:
        big = max(extent)
        self.res = [max(8, round(longest * e / big)) for e in extent]  # x, y, z cells
        self.values = torch.zeros(1, 1, self.res[2], self.res[1], self.res[0], device=device)
        self.device = device
        self.ready = False

    @property
    def cells(self) -> int:
        return self.values.numel()

    @torch.no_grad()
    def refresh(
        self,
        density: Callable[[torch.Tensor], torch.Tensor],
        share: float,
        gen: torch.Generator,
        chunk: int = 1 << 17,
    ) -> None:
        """Evaluate `density` (grid points (M, 3) -> sigma (M,)) at a random point of `share` of
        the cells (all of them when `share` >= 1) and keep the decayed maximum."""
        n = self.cells
        if share >= 1:
            idx = torch.arange(n, device=self.device)
        else:
            idx = torch.randint(0, n, (max(1, int(n * share)),), device=self.device, generator=gen)
        rx, ry, _ = self.res
        x, y, z = idx % rx, (idx // rx) % ry, idx // (rx * ry)
        cell = torch.stack([x, y, z], -1).to(torch.float32)
        jitter = torch.rand(cell.shape, device=self.device, generator=gen)
        size = torch.tensor(self.res, dtype=torch.float32, device=self.device)
        pts = (cell + jitter) / size * 2.0 - 1.0
        flat = self.values.view(-1)
        for a in range(0, len(idx), chunk):
            sigma = density(pts[a : a + chunk]).to(flat.dtype)
            i = idx[a : a + chunk]
            flat[i] = torch.maximum(flat[i] * DECAY, sigma)
        self.ready = True

    def density(self, g: torch.Tensor) -> torch.Tensor:
        """The held density at grid points (M, 3), trilinear between cell centres; 0 outside."""
        grid = g.view(1, -1, 1, 1, 3).to(self.values.dtype)
        v = F.grid_sample(self.values, grid, padding_mode="zeros", align_corners=False)
        return v.view(-1).to(g.dtype)
