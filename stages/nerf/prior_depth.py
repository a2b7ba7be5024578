"""Rays through the frames' depth prior (the user's `--depth-prior`, 01_ingest/depth_prior/, or
a still camera's depth from shading, nerf.shading_depth): relative depth whose scale and shift
are unknown, so it supervises only the shape of each frame's depth (losses.prior_depth,
scale-and-shift invariant as MiDaS's loss is).

Why per frame: a monocular network's map has its own scale and shift in every frame, so a step
takes a few frames and fits one scale and shift to each frame's rays, never across frames. The
pixels are a fixed random draw of each training frame's known pixels, as the stereo rays'.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch


@dataclass
class PriorRays:
    """Each training frame's drawn pixels with the prior there, frame by frame."""

    frame: list[int]  # FrameSet position of each frame that has pixels
    u: list[torch.Tensor]  # (N_f,) per frame
    v: list[torch.Tensor]
    prior: list[torch.Tensor]  # (N_f,) the prior's value (relative)
    weight: float = 0.0  # its loss's weight (nerf.loss.depth_prior_weight, shading_prior_weight)

    def __len__(self) -> int:
        return sum(len(p) for p in self.prior)

    def sample(
        self, frames: int, rays: int, gen: torch.Generator
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """`frames` frames (with replacement), `rays` pixels of each: (frames * rays,) frame
        positions, u, v and prior, frame by frame (reshape to (frames, rays) per frame)."""
        device = self.prior[0].device
        picks = torch.randint(len(self.frame), (frames,), generator=gen, device=device)
        fs, us, vs, ps = [], [], [], []
        for k in picks.tolist():
            n = len(self.prior[k])
            idx = torch.randint(n, (rays,), generator=gen, device=device)
            fs.append(torch.full((rays,), self.frame[k], dtype=torch.long, device=device))
            us.append(self.u[k][idx])
            vs.append(self.v[k][idx])
            ps.append(self.prior[k][idx])
        return torch.cat(fs), torch.cat(us), torch.cat(vs), torch.cat(ps)


def prior_depth_targets(
    prior_of: Callable[[int], np.ndarray | None],
    positions: dict[int, int],
    usable: dict[int, np.ndarray],
    per_frame: int,
    min_pixels: int,
    device: torch.device,
    seed: int = 0,
    weight: float = 0.0,
) -> PriorRays | None:
    """Up to `per_frame` pixels of each training frame in `positions` (frame index -> FrameSet
    position) where its prior (`prior_of(index)`: relative depth, 0 unknown; None: none) is
    known and the frame's mask (`usable`, bool) keeps the pixel; a frame with fewer than
    `min_pixels` such pixels is left out. None when none is left. `weight`: its loss's."""
    rng = np.random.default_rng(seed)
    out = PriorRays([], [], [], [], weight)
    for i, p in sorted(positions.items()):
        prior = prior_of(i)
        if prior is None:
            continue
        keep = (prior > 0) & usable.get(i, np.ones(prior.shape, bool))
        rows, cols = np.nonzero(keep)
        if len(rows) < min_pixels:
            continue
        pick = rng.choice(len(rows), size=min(per_frame, len(rows)), replace=False)
        out.frame.append(p)
        out.u.append(torch.as_tensor(cols[pick], dtype=torch.float32, device=device))
        out.v.append(torch.as_tensor(rows[pick], dtype=torch.float32, device=device))
        out.prior.append(
            torch.as_tensor(prior[rows[pick], cols[pick]], dtype=torch.float32, device=device)
        )
    return out if out.frame else None
