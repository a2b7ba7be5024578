"""05_depth (docs/formats.md): depth/<index>.npy, opacity/<index>.npy, views/<index>.npy,
inferred/<index>.npy, 16-bit PNGs, metrics.json, preview.mp4. `DepthView` is the only reader of
the folder; `DepthMetrics` is metrics.json."""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict

from endopipe.pipeline.stage import read_summary
from endopipe.stages.depth.summary import DepthSummary
from endopipe.stages.metrics.scores import DepthScores, ProtocolScores

DEPTH_DIR = "depth"
OPACITY_DIR = "opacity"
VIEWS_DIR = "views"
INFERRED_DIR = "inferred"
METRICS_FILE = "metrics.json"
PREVIEW_FILE = "preview.mp4"


def frame_file(index: int, suffix: str = ".npy") -> str:
    """The file name of endopipe frame `index` (000012.npy)."""
    return f"{index:06d}{suffix}"


class DepthMetrics(BaseModel):
    """metrics.json: flat protocol blocks (stages.metrics.depth), per frame, and held-out image
    quality. Blocks are present only when they were computed (no ground truth: none of the
    depth ones); further keys from the metrics library are kept as they are."""

    model_config = ConfigDict(extra="allow", ser_json_inf_nan="constants")

    median_scaled: DepthScores | None = None
    sequence_scaled: DepthScores | None = None
    unscaled: DepthScores | None = None
    affine_invariant: DepthScores | None = None
    frames: int | None = None
    per_frame: list[dict] | None = None
    gt_kind: str | None = None  # "exact" | "pseudo" | "relative"
    #: The radial and brightness guesses (stages.metrics.baselines), scored with the same
    #: protocol blocks on the same pixels as ours: {"radial": {"median_scaled": {...}, ...}}.
    baselines: dict[str, ProtocolScores] | None = None
    heldout_frames: list[int] | None = None
    heldout_psnr: float | None = None
    heldout_ssim: float | None = None
    per_frame_image: dict[str, dict[str, float]] | None = None
    #: ours on the pixels other views agree with ("seen_again") and on the rest ("rest"),
    #: each with the headline protocol block (median-scaled, or affine-invariant)
    by_support: dict[str, DepthScores] | None = None


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
        path = self.folder / METRICS_FILE
        return DepthMetrics.model_validate_json(path.read_text()) if path.is_file() else None

    @property
    def preview_path(self) -> Path:
        """preview.mp4: RGB | depth | error (absent when the stage's preview is off)."""
        return self.folder / PREVIEW_FILE
