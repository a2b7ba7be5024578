"""The nerf stage (DESIGN §3 `04_nerf/`): field, sampling, rendering, losses, training."""

from stages.nerf.stage import Nerf

__all__ = ["Nerf"]
