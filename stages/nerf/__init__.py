"""The nerf stage (DESIGN §3 `04_nerf/`): field, sampling, rendering, losses, training."""

from endopipe.stages.nerf.stage import Nerf

__all__ = ["Nerf"]
