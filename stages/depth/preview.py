"""How depth is shown: the colour maps, the scaled relative-error map, and preview.mp4.

One colour map per quantity everywhere: depth in turbo (near = blue), the abs-rel error in
inferno from 0 to ERROR_MAX, black where nothing is asked (outside the field of view, no ground
truth) and NO_DEPTH grey where a depth was asked for and none was found (a hole: depth 0).
The report draws its figures with these maps and the same error (`scaled_error`), so the
preview video and the report agree.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from endopipe.stages.io.video_writer import write_mp4
from endopipe.stages.metrics.depth import affine_fit

#: Colour maps (matplotlib names; OpenCV has the same maps) and the error at the top of the scale.
DEPTH_CMAP = "turbo"
ERROR_CMAP = "inferno"
ERROR_MAX = 0.25
#: The colour of a hole (RGB): mid-grey, at least 95 (of 441) from every colour of turbo and
#: inferno, so a hole never reads as a depth or an error.
NO_DEPTH = (128, 128, 128)
_CV2_MAPS = {"turbo": cv2.COLORMAP_TURBO, "inferno": cv2.COLORMAP_INFERNO}


class FrameImages(Protocol):
    def image(self, i: int) -> np.ndarray: ...


def apply_cmap(x: np.ndarray, cmap: str) -> np.ndarray:
    """Values in [0, 1] through a colour map, as RGB uint8."""
    u8 = (np.clip(x, 0, 1) * 255).astype(np.uint8)
    return cv2.cvtColor(cv2.applyColorMap(u8, _CV2_MAPS[cmap]), cv2.COLOR_BGR2RGB)


def has_depth(depth: np.ndarray) -> np.ndarray:
    """Pixels with a depth (positive and finite; 0 = no depth)."""
    return (depth > 0) & np.isfinite(depth)


def colourise(
    depth: np.ndarray,
    lo: float,
    hi: float,
    cmap: str = DEPTH_CMAP,
    inside: np.ndarray | None = None,
) -> np.ndarray:
    """Depth (or any value) from lo to hi through `cmap` (RGB uint8): pixels without a depth
    NO_DEPTH grey inside the field of view `inside` (everywhere when None), black outside."""
    rgb = apply_cmap((np.nan_to_num(depth) - lo) / max(hi - lo, 1e-9), cmap)
    rgb[~has_depth(depth)] = NO_DEPTH
    if inside is not None:
        rgb[~inside.astype(bool)] = 0
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


def error_map(
    depth: np.ndarray, gt: np.ndarray, affine: bool = False, inside: np.ndarray | None = None
) -> np.ndarray:
    """Per-pixel relative error after median scaling (or, for a relative ground truth, after
    the least-squares scale and shift), 0..ERROR_MAX in ERROR_CMAP; NO_DEPTH grey where the
    truth is valid and ours has no depth (a hole), black where there is no truth or outside
    the field of view `inside`."""
    truth = (gt > 0) & np.isfinite(gt)
    if inside is not None:
        truth &= inside.astype(bool)
    valid = truth & has_depth(depth)
    out = np.zeros((*depth.shape[:2], 3), np.uint8)
    if valid.sum() > 1:
        rel, _, _ = scaled_error(depth.astype(np.float64), gt.astype(np.float64), valid, affine)
        out = apply_cmap(np.where(valid, rel, 0) / ERROR_MAX, ERROR_CMAP)
        out[~valid] = 0
    out[truth & ~valid] = NO_DEPTH
    return out


def label_panel(panel: np.ndarray, title: str, bar: tuple[str, str, str] | None) -> np.ndarray:
    """The panel with its column title above and, for a colour-mapped panel, a colour bar
    below: bar = (colour map, label at the low end, label at the high end), with a NO_DEPTH
    swatch labelled "no depth" in the middle of the labels."""
    h, w = panel.shape[:2]
    scale = max(0.3, w / 480)
    band = max(14, round(34 * scale))
    top = np.full((band, w, 3), 24, np.uint8)
    _put(top, title, (4, band - round(band * 0.3)), scale)
    bar_h = max(6, band // 4 * 2)  # even, from an even row: whole in 4:2:0 chroma
    bottom = np.full((band + bar_h + 2, w, 3), 24, np.uint8)
    if bar is not None:
        cmap, lo, hi = bar
        bottom[2 : 2 + bar_h, 4 : w - 4] = apply_cmap(np.linspace(0, 1, w - 8)[None], cmap)
        y = len(bottom) - round(band * 0.3)
        _put(bottom, lo, (4, y), scale)
        tw = cv2.getTextSize(hi, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0]
        _put(bottom, hi, (max(4, w - 4 - tw), y), scale)
        _hole_legend(bottom, y, scale)
    return np.concatenate([top, panel, bottom], axis=0)


def _hole_legend(band: np.ndarray, baseline: int, scale: float) -> None:
    """A NO_DEPTH swatch and "no depth", centred on the label line of a colour bar."""
    label = "no depth"
    (tw, th), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    x = (band.shape[1] - tw - th - 4) // 2
    band[baseline - th : baseline, x : x + th] = NO_DEPTH
    _put(band, label, (x + th + 4, baseline), scale)


def _put(img: np.ndarray, text: str, org: tuple[int, int], scale: float) -> None:
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (235, 235, 235), 1, cv2.LINE_AA)


def write_preview(
    path: Path,
    ingest: FrameImages,
    depths: dict[int, np.ndarray],
    gt_depths: dict[int, np.ndarray],
    fps: int,
    affine: bool = False,
    units: str = "",
) -> None:
    """RGB | depth | error (when GT exists), one frame per registered frame; each panel with
    its title and, for depth and error, a colour bar with its range. Holes (no depth inside
    the field of view, from `ingest.fov()` when it has one) are NO_DEPTH grey."""
    fov = ingest.fov() if hasattr(ingest, "fov") else None
    inside = fov > 0 if fov is not None else None
    all_d = np.concatenate([d[has_depth(d)] for d in depths.values()]) if depths else np.ones(1)
    lo, hi = np.percentile(all_d, [2, 98]) if all_d.size else (0.0, 1.0)
    unit = f" {units}" if units else ""
    fit = "scale+shift fitted" if affine else "median-scaled"
    bar = (ERROR_CMAP, "0", f"{ERROR_MAX:g}+")
    frames = []
    for i, d in depths.items():
        depth_bar = (DEPTH_CMAP, f"{lo:.3g}", f"{hi:.3g}{unit}")
        panels = [
            label_panel(ingest.image(i), f"frame {i}", None),
            label_panel(
                colourise(d, lo, hi, inside=_fit(inside, d)),
                f"depth ({units or 'scene units'}), grey = no depth",
                depth_bar,
            ),
        ]
        if i in gt_depths:
            error = error_map(d, gt_depths[i], affine, _fit(inside, d))
            panels.append(label_panel(error, f"abs-rel error, {fit}", bar))
        elif gt_depths:  # keep the frame's width: an empty panel where this frame has no truth
            blank = np.zeros((*d.shape[:2], 3), np.uint8)
            panels.append(label_panel(blank, "no ground truth", None))
        frames.append(np.concatenate(panels, axis=1))
    if frames:
        write_mp4(path, frames, fps)


def _fit(mask: np.ndarray | None, like: np.ndarray) -> np.ndarray | None:
    """The field-of-view mask on `like`'s grid (None stays None)."""
    if mask is None or mask.shape == like.shape[:2]:
        return mask
    h, w = like.shape[:2]
    return cv2.resize(mask.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
