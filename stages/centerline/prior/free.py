"""No prior: what `prior: none` (or `auto` when no shape fits) hands on. It still carries the
scene's length scale, so the stages after it size their grids the same way for every case."""

from __future__ import annotations

import numpy as np
import torch

from endopipe.stages.centerline.prior.base import LumenPrior
from endopipe.stages.centerline.prior.tensors import Tensorish, as_tensor, flat_rays, near_far


class FreePrior(LumenPrior):
    """No anatomical prior (`prior: none`, or `auto` when no shape fits the SfM points): no
    wall, no core, rays bounded only by how far the cameras saw points (`reach`). It keeps the
    prior's other job, the scene's length scale (`scale`, one scene unit), so the NeRF, the
    baked surface and the mesh size their grids and steps the same way for every case."""

    kind = "none"

    def __init__(self, centre: Tensorish, scale: float, reach: float, depth: float) -> None:
        self.centre = np.asarray(centre, np.float64).reshape(3)
        self.scale = float(scale)
        self.reach = float(reach)
        self.depth = float(depth)  # median camera-to-point distance (the light's typical r)
        self.weight = 0.0
        self.far_radii = self.reach / max(self.scale, 1e-12)

    @property
    def own_radius(self) -> float:
        return self.scale

    def _buffers(self, device: torch.device, dtype: torch.dtype) -> dict[str, torch.Tensor]:
        return {}

    def signed_distance(self, x: Tensorish) -> torch.Tensor:
        """0 everywhere: every point is as near a possible wall as any other (a band around
        the 'wall' is then all of space)."""
        return torch.zeros(as_tensor(x).shape[:-1])

    def in_core(self, x: Tensorish, fraction: float = 0.5) -> torch.Tensor:
        return torch.zeros(as_tensor(x).shape[:-1], dtype=torch.bool)

    def radius_at(self, x: Tensorish) -> torch.Tensor:
        return torch.full(as_tensor(x).shape[:-1], self.scale)

    def ray_bounds(
        self,
        origins: Tensorish,
        dirs: Tensorish,
        margin: float = 0.25,
        *,
        max_far: float | None = None,
        near_fraction: float = 0.05,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """near: `near_fraction` x scale; far: the reach (past every point the cameras saw)."""
        _, _, dnorm = flat_rays(origins, dirs)
        far = torch.full_like(dnorm, self.reach)
        return near_far(near_fraction, torch.full_like(dnorm, self.scale), far, dnorm)

    def _moved(self, s: float, r: np.ndarray, t: np.ndarray) -> FreePrior:
        return FreePrior(s * r @ self.centre + t, s * self.scale, s * self.reach, s * self.depth)

    def _arrays(self) -> dict[str, np.ndarray]:
        return {
            "centre": self.centre,
            "scale": np.array(self.scale),
            "depth": np.array(self.depth),
        }
