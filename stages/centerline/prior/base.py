"""The interface every lumen prior shape offers the NeRF regulariser, the depth and mesh stages:
signed distance to the wall, the lumen's core, ray bounds and the scene's length scale.
`prior.npz` is storage.py's (`save_prior`, `load_prior`): it knows every shape, so the shapes
import this module and this module imports none of them."""

from __future__ import annotations

import numpy as np
import torch

from endopipe.stages.centerline.prior.tensors import Tensorish


class LumenPrior:
    """Common interface. Distances are in the units of the curve (the cameras' units)."""

    kind: str = "base"

    #: default cap of ray_bounds' far, in multiples of the (median) radius
    far_radii: float = 6.0
    #: how much L_prior may say (the fit's share of SfM depths it explains; 0: no prior)
    weight: float = 1.0
    #: how far the cameras saw SfM points (world units); None: unknown
    reach: float | None = None
    #: the scene's length scale when it is not this prior's radius: a forced prior that fits
    #: badly takes it from the shape that fits (the cavity preset's ellipsoid around a colon is
    #: 2.4x the tube, and grids sized by it were too coarse for the colon's walls)
    unit: float | None = None
    #: how far past the wall sampling must look to reach the SfM points (the wall inflated by
    #: 1 + margin holds `reach_share` of them; 0: unknown). A wall that fits half of C3VD's
    #: points ended a quarter of its rays short of the point they saw.
    margin: float = 0.0
    #: the widest core (as a fraction of the wall, see `in_core`) the SfM points leave empty:
    #: at most `core_share` of them inside (1: not measured, 0: none). C3VD's tube followed the
    #: camera path, and 8% of the points lay in its half-radius core, where a fold juts in.
    core_limit: float = 1.0

    # --- interface ------------------------------------------------------------------------
    def signed_distance(self, x: Tensorish) -> torch.Tensor:
        """(..., 3) -> (...): approximate signed distance to the wall, negative inside."""
        raise NotImplementedError

    def in_core(self, x: Tensorish, fraction: float = 0.5) -> torch.Tensor:
        """(..., 3) -> bool (...): inside the lumen's core (the wall shrunk by `fraction`)."""
        raise NotImplementedError

    def radius_at(self, x: Tensorish) -> torch.Tensor:
        """(..., 3) -> (...): the lumen radius that applies at x."""
        raise NotImplementedError

    def ray_bounds(
        self,
        origins: Tensorish,
        dirs: Tensorish,
        margin: float = 0.25,
        *,
        max_far: float | None = None,
        near_fraction: float = 0.05,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(N,3), (N,3) -> near (N,), far (N,) in units of `dirs` (x = o + t d).

        far: where the ray leaves the wall inflated by (1 + margin), capped at `max_far`
        (default `far_radii` x the median radius); near: `near_fraction` x the radius at the
        origin, and never more than half of far.
        """
        raise NotImplementedError

    @property
    def typical_radius(self) -> float:
        """The scene's length scale (one NeRF scene unit; the mesh's voxels follow it): the
        prior's own radius, unless `unit` says otherwise."""
        return float(self.unit) if self.unit else self.own_radius

    @property
    def own_radius(self) -> float:
        raise NotImplementedError

    def _arrays(self) -> dict[str, np.ndarray]:
        raise NotImplementedError

    # --- moving ---------------------------------------------------------------------------
    def moved(self, s: float, r: np.ndarray, t: np.ndarray) -> LumenPrior:
        """This prior in other coordinates, x -> s R x + t (one case's prior placed in another
        reconstruction of the same scene): lengths scale by s, shares and fractions stay."""
        out = self._moved(float(s), np.asarray(r, np.float64), np.asarray(t, np.float64))
        out.weight = self.weight
        out.reach = None if self.reach is None else self.reach * s
        out.unit = None if self.unit is None else self.unit * s
        out.margin = self.margin
        out.core_limit = self.core_limit
        return out

    def _moved(self, s: float, r: np.ndarray, t: np.ndarray) -> LumenPrior:
        raise NotImplementedError

    def to(self, device: str | torch.device) -> LumenPrior:
        """Warm the buffers for `device` (queries move them on demand anyway)."""
        self._buffers(torch.device(device), torch.float32)
        return self

    def _buffers(self, device: torch.device, dtype: torch.dtype) -> dict[str, torch.Tensor]:
        raise NotImplementedError
