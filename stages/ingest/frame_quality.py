"""Per-frame quality cues for ingest: blur and near-duplicate frames.

Absolute sharpness depends on the scene, the optics and the resolution, so blur is judged
relative to the sequence's own median; duplicates are judged on small grey copies, which are
cheap and insensitive to noise and compression.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field


class QualityConfig(BaseModel):
    """Thresholds for dropping blurred and near-duplicate frames."""

    model_config = ConfigDict(extra="forbid")

    blur_rel_threshold: float = Field(
        0.4,
        ge=0.0,
        le=1.0,
        description="A frame is blurred when its sharpness is under this fraction of the "
        "sequence's median sharpness.",
    )
    duplicate_threshold: float = Field(
        0.003,
        ge=0.0,
        le=1.0,
        description="Two frames are near duplicates when their mean absolute grey difference "
        "(0..1, on downsampled copies) is under this. JPEG re-encoding or sensor noise give "
        "~0.001-0.0025; a 1 px shift of a real endoscopy frame gives ~0.005.",
    )
    diff_size: int = Field(
        128,
        ge=8,
        description="Long side, in pixels, of the grey copies compared by frame_difference.",
    )


def to_gray(image: np.ndarray) -> np.ndarray:
    """Grey float32 in 0..255 from an RGB (HxWx3) or grey (HxW) image."""
    if image.ndim == 3:
        image = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    return image.astype(np.float32)


def sharpness(image: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Variance of the Laplacian inside the mask (255 = use): high for sharp frames.

    The mask is eroded first so the edge of the scope border or of a masked highlight, which is
    sharp in every frame, does not count as image detail.
    """
    lap = cv2.Laplacian(to_gray(image), cv2.CV_32F, ksize=3)
    if mask is None:
        return float(lap.var())
    inner = cv2.erode((mask > 0).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    if not inner.any():
        return 0.0
    return float(lap[inner].var())


def is_blurred(score: float, reference_scores: Sequence[float], rel_threshold: float) -> bool:
    """True when `score` is under `rel_threshold` times the median of the sequence's scores."""
    if len(reference_scores) == 0:
        return False
    return bool(score < rel_threshold * float(np.median(reference_scores)))


def frame_difference(
    a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None, size: int = 128
) -> float:
    """Mean absolute difference of small grey copies of two frames, in 0..1 (0 = identical)."""
    if a.shape[:2] != b.shape[:2]:
        raise ValueError(f"frames differ in size: {a.shape[:2]} vs {b.shape[:2]}")
    h, w = a.shape[:2]
    scale = min(1.0, size / max(h, w))
    dsize = (max(1, round(w * scale)), max(1, round(h * scale)))
    ga, gb = (cv2.resize(to_gray(x), dsize, interpolation=cv2.INTER_AREA) for x in (a, b))
    diff = np.abs(ga - gb) / 255.0
    if mask is None:
        return float(diff.mean())
    # Only small pixels lying wholly inside the mask count.
    valid = cv2.resize((mask > 0).astype(np.float32), dsize, interpolation=cv2.INTER_AREA) > 0.99
    return float(diff[valid].mean()) if valid.any() else 0.0
