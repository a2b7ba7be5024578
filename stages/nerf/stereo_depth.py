"""Depth targets from a stereo rig's depth maps (the ingest stage's stereo/): dense, metric,
and measured from two places at once, so a camera that stands still has depth too.

Why as rays like the SfM points': the same Huber on the relative error (losses.sparse_depth)
suits a matcher's depth, whose error grows with the distance and which is wrong at occlusion
edges; the pixels are a fixed random draw of each training frame's matched pixels, so a step
costs the same few hundred rays whatever the frames' size.
"""

from __future__ import annotations

import numpy as np
import torch

from endopipe.stages.nerf.sparse_depth import SparseDepth


def stereo_depth_targets(
    ingest,
    positions: dict[int, int],
    world_per_mm: float,
    scene_scale: float,
    per_frame: int,
    device: torch.device,
    seed: int = 0,
) -> SparseDepth | None:
    """Up to `per_frame` matched pixels of each training frame in `positions` (frame index ->
    FrameSet position), their depth in scene units (mm * `world_per_mm` / `scene_scale`).
    None when no training frame has stereo depth."""
    rng = np.random.default_rng(seed)
    frame, us, vs, zs = [], [], [], []
    for i, p in sorted(positions.items()):
        depth = ingest.stereo_depth(i)
        if depth is None:
            continue
        rows, cols = np.nonzero(depth > 0)
        if len(rows) == 0:
            continue
        pick = rng.choice(len(rows), size=min(per_frame, len(rows)), replace=False)
        frame.append(np.full(len(pick), p, np.int64))
        us.append(cols[pick].astype(np.float32))
        vs.append(rows[pick].astype(np.float32))
        zs.append(depth[rows[pick], cols[pick]].astype(np.float64))
    if not frame:
        return None

    def t(parts: list[np.ndarray], dtype=torch.float32) -> torch.Tensor:
        return torch.as_tensor(np.concatenate(parts), dtype=dtype, device=device)

    z = np.concatenate(zs) * world_per_mm / scene_scale
    return SparseDepth(
        frame=t(frame, torch.long),
        u=t(us),
        v=t(vs),
        z=torch.as_tensor(z, dtype=torch.float32, device=device),
    )
