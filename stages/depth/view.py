"""05_depth (docs/formats.md): depth/<index>.npy, opacity/<index>.npy, views/<index>.npy,
inferred/<index>.npy, 16-bit PNGs, metrics.json, preview.mp4. `DepthView` is the only reader of
the folder; metrics.json is `DepthMetrics` (metrics_file.py)."""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

import numpy as np

from endopipe.pipeline.stage import read_summary
from endopipe.stages.depth.metrics_file import DepthMetrics
from endopipe.stages.depth.summary import DepthSummary

DEPTH_DIR = "depth"
OPACITY_DIR = "opacity"
VIEWS_DIR = "views"
INFERRED_DIR = "inferred"
PREVIEW_FILE = "preview.mp4"


def frame_file(index: int, suffix: str = ".npy") -> str:
    """The file name of endopipe frame `index` (000012.npy)."""
    return f"{index:06d}{suffix}"


class DepthView:
    """Typed access to 05_depth: depth maps by endopipe frame index."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.indices = sorted(
            int(p.stem) for p in (self.folder / DEPTH_DIR).glob("*.npy") if p.stem.isdigit()
        )

    @cached_property
    def summary(self) -> DepthSummary:
        """The stage's summary in its manifest, as the model the stage wrote (SummaryMismatch
        when the folder was written with other fields)."""
        return read_summary(self.folder, DepthSummary)

    def depth_path(self, index: int) -> Path:
        return self.folder / DEPTH_DIR / frame_file(index)

    def has_depth(self, index: int) -> bool:
        return self.depth_path(index).is_file()

    def depth(self, index: int) -> np.ndarray:
        """float32 z-depth in the units of cameras.json, 0 = invalid."""
        return np.load(self.depth_path(index))

    def opacity(self, index: int) -> np.ndarray | None:
        """Accumulated opacity of the rendered rays (0..1), or None when not written."""
        return self._optional(OPACITY_DIR, index)

    def views(self, index: int) -> np.ndarray | None:
        """uint8 per depth pixel: how many nearby frames see its surface point where their own
        depth puts it (`support.consistent_views`; 0 where no depth), or None when not written.
        A count of observations, not a measure of accuracy (docs/results.md)."""
        return self._optional(VIEWS_DIR, index)

    def inferred(self, index: int) -> np.ndarray | None:
        """Pixels whose depth lies under the frame's own mask (a specular highlight, a masked
        tool): the field's surface there, never observed in this frame; None when not written."""
        return self._optional(INFERRED_DIR, index)

    def _optional(self, sub: str, index: int) -> np.ndarray | None:
        """A per-frame map of folder `sub`, or None when the stage did not write it."""
        path = self.folder / sub / frame_file(index)
        return np.load(path) if path.is_file() else None

    @property
    def metrics(self) -> DepthMetrics | None:
        """metrics.json (both protocols, per frame, held-out PSNR / SSIM); None when absent."""
        return DepthMetrics.read(self.folder)

    @property
    def preview_path(self) -> Path:
        """preview.mp4: RGB | depth | error (absent when the stage's preview is off)."""
        return self.folder / PREVIEW_FILE
