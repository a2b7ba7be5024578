"""Anatomical lumen priors usable from torch (seed §3.3): a tube around a centre curve, or a cavity.

The NeRF regulariser needs three things of the lumen, for many points at once and on the GPU:
a signed distance to the estimated wall (negative inside the lumen), whether a point lies in
the lumen's core (where density should vanish), and near/far bounds for rays cast from inside.

- `TubePrior` (tube.py): a polyline centre curve with a radius per sample.
- `EllipsoidPrior` (ellipsoid.py): a cavity as an ellipsoid.
- `FreePrior` (free.py): no wall, only the scene's length scale and how far the cameras saw.

All accept torch tensors (or arrays) of shape (..., 3) on any device and return tensors; all
round-trip through `prior.npz` (storage.py: `save_prior`, `load_prior`). No pipeline imports:
the NeRF stage and plain scripts use this package alone. The fits that make these shapes from
the camera path and the SfM points live beside it (tube.py, cavity.py, choose.py).
"""

from endopipe.stages.centerline.prior.base import LumenPrior
from endopipe.stages.centerline.prior.ellipsoid import EllipsoidPrior
from endopipe.stages.centerline.prior.free import FreePrior
from endopipe.stages.centerline.prior.storage import load_prior, save_prior
from endopipe.stages.centerline.prior.tube import TubePrior

__all__ = ["EllipsoidPrior", "FreePrior", "LumenPrior", "TubePrior", "load_prior", "save_prior"]
