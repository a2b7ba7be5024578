"""Depth targets from the SfM points (as in DS-NeRF): the poses stage's tracks tell, for a few
hundred pixels per frame, how far the surface is, in the poses' own scale.

Why: the photometric loss with a learned light gain is blind to a uniform scaling of the walls
about the camera path, and training drifts there run by run (on the 60-frame colon the field
came out 1.1-2.8% short with one setting and two seeds, and the mesh 6.3-7.5% of the radius
off). The sparse points are triangulated from the same poses, so they pin that scale.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from endopipe.stages.poses.view import SparseObservations


@dataclass
class SparseDepth:
    """Training rays with a depth target: frame positions in the FrameSet, pixels, scene z."""

    frame: torch.Tensor  # (N,) long
    u: torch.Tensor  # (N,)
    v: torch.Tensor  # (N,)
    z: torch.Tensor  # (N,) scene z-depth
    min_angle: float = 0.0  # the viewing angle (degrees) the points were kept from

    def __len__(self) -> int:
        return int(self.frame.shape[0])

    def draw(self, n: int, gen: torch.Generator) -> torch.Tensor:
        """`n` rows drawn at random (with replacement)."""
        return torch.randint(len(self), (n,), generator=gen, device=self.frame.device)

    def sample(self, n: int, gen: torch.Generator) -> tuple[torch.Tensor, ...]:
        k = self.draw(n, gen)
        return self.frame[k], self.u[k], self.v[k], self.z[k]


def sparse_depth_targets(
    obs: SparseObservations | None,
    positions: dict[int, int],
    c2w_world: dict[int, np.ndarray],
    scene_scale: float,
    size: tuple[int, int],
    min_track: int,
    max_error: float,
    min_angle: float,
    device: torch.device,
    usable: np.ndarray | None = None,
) -> SparseDepth | None:
    """The observations of the frames in `positions` (frame index -> FrameSet position, the
    training frames only), with track length >= `min_track`, reprojection error <= `max_error`
    px, seen under >= `min_angle` degrees (`SparseObservations.angle`), in front of the camera
    and inside the image (and on a `usable` pixel, (H, W) bool, when given: one the lens model
    reaches); z-depth in scene units (world / scale). The angle never drops more than half the
    points otherwise kept: a camera that barely moves sees them all under a narrow angle, and
    the wider half still pins the scale better than none."""
    if obs is None or not positions:
        return None
    h, w = size
    keep = np.isin(obs.frame, list(positions)) & (obs.track >= min_track)
    keep &= obs.error <= max_error
    keep &= (obs.uv[:, 0] >= 0) & (obs.uv[:, 0] <= w - 1)
    keep &= (obs.uv[:, 1] >= 0) & (obs.uv[:, 1] <= h - 1)
    if usable is not None:
        col = np.clip(np.round(obs.uv[:, 0]), 0, w - 1).astype(np.int64)
        row = np.clip(np.round(obs.uv[:, 1]), 0, h - 1).astype(np.int64)
        keep &= usable[row, col]
    if min_angle > 0 and keep.any():
        min_angle = min(min_angle, float(np.median(obs.angle[keep])))
        keep &= obs.angle >= min_angle
    idx = np.nonzero(keep)[0]
    if len(idx) == 0:
        return None
    z = np.empty(len(idx))
    for f in np.unique(obs.frame[idx]):
        sel = obs.frame[idx] == f
        w2c = np.linalg.inv(c2w_world[int(f)])
        z[sel] = obs.xyz[idx[sel]] @ w2c[2, :3] + w2c[2, 3]
    front = z > 0
    idx, z = idx[front], z[front]
    if len(idx) == 0:
        return None

    def t(a: np.ndarray, dtype=torch.float32) -> torch.Tensor:
        return torch.as_tensor(a, dtype=dtype, device=device)

    pos = np.array([positions[int(f)] for f in obs.frame[idx]], dtype=np.int64)
    return SparseDepth(
        frame=t(pos, torch.long),
        u=t(obs.uv[idx, 0]),
        v=t(obs.uv[idx, 1]),
        z=t(z / scene_scale),
        min_angle=min_angle,
    )
