"""What the poses stage and its COLMAP module share: the estimate of any source and the
progress-bar type (kept apart so that stage.py and colmap_sfm.py need not import each other)."""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from endopipe.stages.camera import Camera

#: ctx.progress: (description, total) -> context manager yielding advance(n=1, info=None)
ProgressFactory = Callable[[str, int | None], AbstractContextManager[Callable[..., None]]]


@dataclass
class Estimate:
    """Poses from any source (SfM, ground truth, a file), before alignment and writing."""

    camera: Camera  # the one shared camera, with its lens distortion
    colmap_model: str  # the COLMAP model it is (was estimated / is written) as
    c2w: dict[int, np.ndarray]
    xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    rgb: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.uint8))
    reconstruction: Any = None  # pycolmap.Reconstruction: SfM's, or the known poses' tracks
    info: dict[str, Any] = field(default_factory=dict)
    intrinsics_kind: str = "fixed"
    alternatives: dict[str, dict[int, np.ndarray]] = field(default_factory=dict)  # not kept
    verdict: Any = None  # PoseVerdict of SfM poses (None: not assessed, e.g. ground truth)
    #: an estimated lens: how far from the principal point (px) the features it was fitted to
    #: reach (None: the lens was given)
    fitted_radius_px: float | None = None
