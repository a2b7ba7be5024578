"""Pixel masks for ingest: the endoscope's field of view and its specular highlights.

Masks follow docs/formats.md: uint8, 255 = use this pixel, 0 = ignore it. The one exception is
`specular_mask`, which marks the highlights themselves (255 = highlight, to be excluded);
`combine` turns the two into the mask ingest writes.

Field of view: the black border of an endoscope image is the dark region *connected to the image
edge* (a dark lumen in the middle is not border). The bright rest is cleaned, replaced by its
convex hull and snapped to a clean shape: a fitted circle (laparoscopes), the hull polygon
(octagonal colonoscope masks with cut corners), its bounding box (black bars) or the full frame.
"""

from __future__ import annotations

import cv2
import numpy as np

from endopipe.stages.ingest.config import FovConfig, FovShape, SpecularConfig


def fov_mask(rgb: np.ndarray, cfg: FovConfig) -> tuple[np.ndarray, FovShape]:
    """Field-of-view mask of one RGB (or grey) frame, 255 inside, and its shape.

    "octagon" stands for any convex polygon with cut corners (the hull is kept as it is). A
    frame with nothing bright in it gives "full": use fov_mask_for_sequence for videos.
    """
    if not cfg.enabled:
        return _full(rgb.shape[:2]), "full"
    return _fov_from_brightness(_brightness(rgb), cfg)


def fov_mask_for_sequence(frames: list[np.ndarray], cfg: FovConfig) -> tuple[np.ndarray, FovShape]:
    """One field-of-view mask for a whole video: the scope border does not move.

    A high per-pixel percentile of brightness over a sample of frames sees the lumen, dark in
    one frame, lit in another, so the mask depends on the optics and not on one frame's content.
    """
    if not frames:
        raise ValueError("fov_mask_for_sequence needs at least one frame")
    if not cfg.enabled:
        return _full(frames[0].shape[:2]), "full"
    idx = np.unique(np.linspace(0, len(frames) - 1, min(cfg.sample_frames, len(frames))).round())
    stack = np.stack([_brightness(frames[int(i)]) for i in idx])
    level = np.percentile(stack, cfg.sequence_percentile, axis=0, method="nearest")
    return _fov_from_brightness(level.astype(np.uint8), cfg)


def specular_mask(
    rgb: np.ndarray, cfg: SpecularConfig, fov: np.ndarray | None = None
) -> np.ndarray:
    """255 where a specular highlight is (to be excluded), 0 elsewhere; uint8 HxW.

    Two tests, after Arnold et al. 2010: an absolute one (bright and white) for saturated
    highlights, and a relative one (whiteness, the min of R, G, B, well above that of the
    local background) for unsaturated highlights on darker tissue. Whiteness rather than
    brightness, so bright but pink tissue is not flagged. Holes in blobs are filled, small
    specks dropped, the rest dilated over the halo.
    """
    h, w = rgb.shape[:2]
    if not cfg.enabled:
        return np.zeros((h, w), np.uint8)
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
    sat, val = hsv[..., 1], hsv[..., 2]
    absolute = (val >= cfg.min_value) & (sat <= cfg.max_saturation)
    white = rgb.min(axis=2)
    background = _local_background(_fill_outside(white, fov), cfg.background_frac)
    relative = (white >= cfg.rel_min_white) & (
        white.astype(np.float32) >= cfg.rel_ratio * background
    )
    candidate = absolute | relative
    if fov is not None:
        candidate &= fov > 0
    # A large highlight is its own local background, so the relative test leaves a hole in it.
    candidate |= ~candidate & ~_touching_edge(~candidate, connectivity=4)
    kept = _drop_small(candidate.astype(np.uint8), cfg.min_blob_px)
    if cfg.dilate_px > 0:
        kept = cv2.dilate(kept, _disk(cfg.dilate_px))
    if fov is not None:
        kept[fov == 0] = 0
    return kept * np.uint8(255)


def combine(fov: np.ndarray, specular: np.ndarray) -> np.ndarray:
    """The mask ingest writes: 255 inside the field of view and not on a highlight."""
    return np.where((fov > 0) & (specular == 0), 255, 0).astype(np.uint8)


# --- field of view ---------------------------------------------------------------------------


def _brightness(rgb: np.ndarray) -> np.ndarray:
    """Max of the channels (HSV value): dark-red tissue stays bright, only black is dark."""
    if rgb.ndim == 2:
        return rgb.astype(np.uint8)
    return rgb.max(axis=2).astype(np.uint8)


def _full(shape: tuple[int, ...]) -> np.ndarray:
    return np.full(shape[:2], 255, np.uint8)


def _fov_from_brightness(level: np.ndarray, cfg: FovConfig) -> tuple[np.ndarray, FovShape]:
    """Border = dark pixels connected to the image edge; the rest, cleaned and hulled."""
    h, w = level.shape
    bright = _not_border(cv2.medianBlur(level, 5), cfg.black_threshold)
    open_px = cfg.open_frac * min(h, w)
    bright = _largest_component(_open(bright, open_px))
    if not bright.any():
        return _full((h, w)), "full"
    contours, _ = cv2.findContours(bright, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    hull = cv2.convexHull(np.concatenate(contours))
    hull_mask = np.zeros((h, w), np.uint8)
    cv2.fillConvexPoly(hull_mask, hull, 1)
    if hull_mask.mean() >= cfg.full_frac:
        return _full((h, w)), "full"
    mask, shape = _snap_shape(hull_mask, hull, cfg)
    if cfg.cut_overlays:
        mask[_overlay_boxes(mask, _open(1 - bright, open_px)) > 0] = 0
    if cfg.erode_px > 0:
        mask = cv2.erode(mask, _disk(cfg.erode_px))
    return mask * np.uint8(255), shape


def _not_border(level: np.ndarray, threshold: int) -> np.ndarray:
    """1 everywhere except the dark regions that touch the image edge."""
    return (~_touching_edge(level < threshold, connectivity=8)).astype(np.uint8)


def _touching_edge(binary: np.ndarray, connectivity: int) -> np.ndarray:
    """The connected components of `binary` that reach the image edge."""
    n, labels = cv2.connectedComponents(binary.astype(np.uint8), connectivity=connectivity)
    at_edge = np.zeros(n, bool)
    at_edge[np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])] = True
    at_edge[0] = False  # label 0 is everything outside `binary`
    return at_edge[labels]


def _open(mask: np.ndarray, size: float) -> np.ndarray:
    radius = int(round(size / 2))
    return cv2.morphologyEx(mask, cv2.MORPH_OPEN, _disk(radius)) if radius > 0 else mask


def _largest_component(mask: np.ndarray) -> np.ndarray:
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return np.zeros_like(mask)
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    return (labels == best).astype(np.uint8)


def _snap_shape(
    hull_mask: np.ndarray, hull: np.ndarray, cfg: FovConfig
) -> tuple[np.ndarray, FovShape]:
    """Replace the hull by the clean shape it is closest to."""
    x, y, bw, bh = cv2.boundingRect(hull)
    if hull_mask.sum() >= cfg.rectangle_fill * bw * bh:
        rect = np.zeros_like(hull_mask)
        rect[y : y + bh, x : x + bw] = 1
        return rect, "rectangle"
    circle = _fit_circle(hull_mask)
    if circle is not None and circle[3] <= cfg.circle_tol:
        cx, cy, r, _ = circle
        disk = np.zeros_like(hull_mask)
        cv2.circle(disk, (round(cx), round(cy)), round(r), 1, thickness=-1)
        return disk, "circle"
    return hull_mask, "octagon"


def _overlay_boxes(shape_mask: np.ndarray, not_tissue: np.ndarray) -> np.ndarray:
    """The solid non-tissue patches inside the shape that are boxes: each must fill its own
    bounding box (clipped to the shape). A dark lumen reaching the border is irregular, so it
    stays in the mask; burned-in boxes are axis-aligned rectangles."""
    inside = (not_tissue > 0) & (shape_mask > 0)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(inside.astype(np.uint8), connectivity=8)
    boxes = np.zeros_like(shape_mask)
    for i in range(1, n):
        x, y, bw, bh, area = stats[i]
        window = shape_mask[y : y + bh, x : x + bw] > 0
        if area >= 0.9 * window.sum():
            boxes[y : y + bh, x : x + bw][labels[y : y + bh, x : x + bw] == i] = 1
    return boxes


def _fit_circle(hull_mask: np.ndarray) -> tuple[float, float, float, float] | None:
    """Least-squares circle through the hull outline, ignoring where it runs along its bounding
    box (a laparoscope's disc is often cut by the frame, or by a dark line of rows just inside
    it). Returns cx, cy, r, rms/r."""
    contours, _ = cv2.findContours(hull_mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    pts = np.concatenate(contours)[:, 0, :].astype(np.float64)
    lo, hi = pts.min(axis=0) + 3, pts.max(axis=0) - 3
    pts = pts[((pts > lo) & (pts < hi)).all(axis=1)]
    if len(pts) < 20:
        return None
    # Kasa fit: x^2 + y^2 = a x + b y + c is linear in a, b, c.
    design = np.column_stack([pts[:, 0], pts[:, 1], np.ones(len(pts))])
    target = (pts**2).sum(axis=1)
    (a, b, c), *_ = np.linalg.lstsq(design, target, rcond=None)
    cx, cy = a / 2, b / 2
    r2 = c + cx**2 + cy**2
    if r2 <= 0:
        return None
    r = float(np.sqrt(r2))
    resid = np.hypot(pts[:, 0] - cx, pts[:, 1] - cy) - r
    # The hull must see enough of the circle: its outline should go most of the way round.
    angles = np.arctan2(pts[:, 1] - cy, pts[:, 0] - cx)
    coverage = len(np.unique(np.floor((angles + np.pi) / (2 * np.pi) * 36))) / 36
    if coverage < 0.5:
        return None
    return float(cx), float(cy), r, float(np.sqrt(np.mean(resid**2)) / r)


# --- specular --------------------------------------------------------------------------------


def _local_background(val: np.ndarray, frac: float) -> np.ndarray:
    """Median brightness of the surroundings, computed at low resolution for speed."""
    h, w = val.shape
    scale = min(1.0, 160.0 / min(h, w))
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    small = cv2.resize(val, size, interpolation=cv2.INTER_AREA)
    k = max(3, int(round(frac * min(small.shape))) | 1)
    bg = cv2.medianBlur(small, k)
    return cv2.resize(bg, (w, h), interpolation=cv2.INTER_LINEAR).astype(np.float32)


def _fill_outside(img: np.ndarray, fov: np.ndarray | None) -> np.ndarray:
    """Outside the field of view, the median inside: the black border must not make tissue at
    the rim look bright next to its 'background'."""
    if fov is None or not (fov > 0).any() or (fov > 0).all():
        return img
    filled = img.copy()
    filled[fov == 0] = np.median(img[fov > 0])
    return filled


def _drop_small(mask: np.ndarray, min_px: int) -> np.ndarray:
    if min_px <= 1:
        return mask
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    keep = np.zeros(n, np.uint8)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_px
    return keep[labels]


def _disk(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
