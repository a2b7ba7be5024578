"""Rectified right views that come with an input's left frames (Hamlyn's image02/, SCARED's
stacked video, a user's `--right FOLDER`): what a stereo matcher needs and nothing more.

Why a type of its own: readers of different layouts find the right eye in different places
(files, half of a video frame), and the matcher must not know which. The rig is rectified: the
right camera is the left one moved by `baseline_mm` along the left camera's +x (OpenCV axes,
docs/formats.md), with the same intrinsics, so a pixel's disparity d gives z = fx * baseline / d.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from endopipe.pipeline.cache import digest_text

#: Baselines outside this range (mm) are a unit or file mix-up, not an endoscope.
BASELINE_RANGE_MM = (0.5, 100.0)


@dataclass(frozen=True)
class StereoPairs:
    """The right view of each left frame, by the left frame's source_index."""

    #: The right image (HxWx3 uint8 RGB, the left frame's size) of a source_index; None when
    #: that frame has no right view.
    right: Callable[[int], np.ndarray | None]
    #: Distance between the two optical centres, in millimetres (positive).
    baseline_mm: float
    #: Where the rig was read ("Hamlyn calibration", "endoscope_calibration.yaml", "--right").
    source: str
    #: Identifies the right views for the cache (e.g. a digest of their files).
    identity: str = ""

    def digest(self) -> str:
        """The right views and the baseline are part of the input: a change re-runs ingest."""
        return digest_text(f"stereo|{self.baseline_mm:.6f}|{self.source}|{self.identity}")
