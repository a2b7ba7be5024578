"""Metric depth a data set ships beside its frames (EndoNeRF's `depth/` when its `endonerf.json`
says millimetres): measured by the data set's makers from their stereo rig, so it does what a
rig's matched depth does here (docs/architecture.md): it supervises the field in millimetres and
fixes the poses' scale.

Why a type of its own, beside `StereoPairs`: the ingest stage takes these maps as they are (no
matcher, no baseline), and must not know which layout they came from. Depth in unknown units
(EndoNeRF as released names none) is not this: its reader gives it as a relative depth prior.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from endopipe.pipeline.cache import digest_text


@dataclass(frozen=True)
class GivenDepth:
    """The data set's depth of each frame, by the frame's source_index."""

    #: float32 z-depth in mm (0 = unknown) at the source frame's size; None when that frame
    #: has none.
    depth: Callable[[int], np.ndarray | None]
    #: Where the maps were read and what made them.
    source: str
    #: Identifies the maps for the cache (a digest of their files).
    identity: str = ""

    def digest(self) -> str:
        """The maps are part of the input: a changed map re-runs ingest."""
        return digest_text(f"given depth|{self.source}|{self.identity}")
