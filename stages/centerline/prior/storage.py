"""`prior.npz`: one file for every prior shape, so the stages after centerline (NeRF, depth,
mesh) and plain scripts read the prior back without knowing which shape was fitted."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from endopipe.stages.centerline.prior.base import LumenPrior
from endopipe.stages.centerline.prior.ellipsoid import EllipsoidPrior
from endopipe.stages.centerline.prior.free import FreePrior
from endopipe.stages.centerline.prior.tube import TubePrior


def save_prior(prior: LumenPrior, path: str | Path) -> None:
    """Write `prior.npz`: the kind, the settings every shape shares (written only when they
    differ from the defaults), and the shape's own arrays."""
    arrays = {
        "kind": np.array(prior.kind),
        "far_radii": np.array(prior.far_radii),
        "weight": np.array(prior.weight),
    }
    if prior.reach is not None:
        arrays["reach"] = np.array(prior.reach)
    if prior.unit is not None:
        arrays["unit"] = np.array(prior.unit)
    if prior.margin:
        arrays["margin"] = np.array(prior.margin)
    if prior.core_limit < 1.0:
        arrays["core_limit"] = np.array(prior.core_limit)
    arrays.update(prior._arrays())
    with open(path, "wb") as fh:  # np.savez would append ".npz" to a path without it
        np.savez(fh, **arrays)


def load_prior(path: str | Path) -> LumenPrior:
    """The prior stored in `prior.npz` (TubePrior, EllipsoidPrior or FreePrior)."""
    with np.load(path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    kind = str(data["kind"])
    far_radii = float(data.get("far_radii", 6.0))
    prior: LumenPrior
    if kind == "tube":
        prior = TubePrior(
            data["points"],
            data["radius"],
            open_ends=bool(data.get("open_ends", True)),
            far_radii=far_radii,
        )
    elif kind == "cavity":
        prior = EllipsoidPrior(data["centre"], data["axes"], data["rotation"], far_radii=far_radii)
    elif kind == "none":
        prior = FreePrior(
            data["centre"], float(data["scale"]), float(data["reach"]), float(data["depth"])
        )
    else:
        raise ValueError(f"{path}: unknown prior kind {kind!r}")
    prior.weight = float(data.get("weight", 1.0))
    if "reach" in data:
        prior.reach = float(data["reach"])
    if "unit" in data:
        prior.unit = float(data["unit"])
    prior.margin = float(data.get("margin", 0.0))
    prior.core_limit = float(data.get("core_limit", 1.0))
    return prior
