"""How depth is shown: the colour map, the scaled relative-error map, and preview.mp4.

The report draws its depth figures with the same error (`scaled_error`), so the numbers in the
preview video and in the report's figures are computed once.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from endopipe.stages.io.video_writer import write_mp4
from endopipe.stages.metrics.depth import affine_fit


class FrameImages(Protocol):
    def image(self, i: int) -> np.ndarray: ...


def colourise(depth: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Depth as a turbo colour map (RGB uint8), invalid pixels black."""
    x = np.clip((depth - lo) / max(hi - lo, 1e-9), 0, 1)
    rgb = cv2.cvtColor(
        cv2.applyColorMap((x * 255).astype(np.uint8), cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB
    )
    rgb[depth <= 0] = 0
    return rgb


def scaled_error(
    depth: np.ndarray, gt: np.ndarray, valid: np.ndarray, affine: bool = False
) -> tuple[np.ndarray, float, float]:
    """|s·depth + b − gt| / gt on `valid` pixels (NaN elsewhere, float32), with s the median
    ratio gt / depth and b = 0 (the monocular protocol), or, for a relative ground truth, the
    least-squares scale and shift. Computed in the inputs' dtype; returns (error, s, b)."""
    p, g = depth[valid], gt[valid]
    if affine:
        s, b = affine_fit(p, g)
    else:
        s, b = np.median(g) / np.median(p), 0.0
    error = np.full(depth.shape, np.nan, np.float32)
    error[valid] = np.abs(p * s + b - g) / g
    return error, float(s), float(b)


def error_map(depth: np.ndarray, gt: np.ndarray, affine: bool = False) -> np.ndarray:
    """Per-pixel relative error after median scaling (or, for a relative ground truth, after
    the least-squares scale and shift), 0..0.3 mapped to the colour map."""
    valid = (gt > 0) & (depth > 0)
    err = np.zeros_like(depth)
    if valid.sum() > 1:
        rel, _, _ = scaled_error(depth.astype(np.float64), gt.astype(np.float64), valid, affine)
        err = np.where(valid, rel, 0).astype(err.dtype)
    out = colourise(err, 0.0, 0.3)
    out[~valid] = 0
    return out


def write_preview(
    path: Path,
    ingest: FrameImages,
    depths: dict[int, np.ndarray],
    gt_depths: dict[int, np.ndarray],
    fps: int,
    affine: bool = False,
) -> None:
    """RGB | depth | error (when GT exists), one frame per registered frame."""
    all_d = np.concatenate([d[d > 0] for d in depths.values()]) if depths else np.ones(1)
    lo, hi = np.percentile(all_d, [2, 98]) if all_d.size else (0.0, 1.0)
    frames = []
    for i, d in depths.items():
        panels = [ingest.image(i), colourise(d, lo, hi)]
        if i in gt_depths:
            panels.append(error_map(d, gt_depths[i], affine))
        frames.append(np.concatenate(panels, axis=1))
    if frames:
        write_mp4(path, frames, fps)
