"""How each depth pixel was seen: by how many other frames, and whether its own frame saw it.

A depth map is rendered from one field for every frame, so each pixel's surface point can be
checked against the other frames' maps: project it into a nearby frame and ask whether that
frame's depth puts a surface there too (within a relative tolerance). A point two other views
agree on was seen from several places; a point no other view confirms rests on one view (or on
the field's guess between views). The maps come from one field, so views agree wherever they
see its surface: the count says how often a surface was observed, not how accurate its depth
is (on C3VD the error is the same at every count and parallax; on the bench colon the few
pixels fewer than two other views see are 4x worse). Pixels the frame's own mask left out (specular
highlights, masked tools) get the surface under them from the field, fitted to the pixels
around them and to other frames: they are flagged as inferred, never counted as observed. So
are the pixels past the radius where an estimated lens was fitted to tracked features: their
rays come from the lens model extrapolated (C3VD's outer ring).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from endopipe.stages.camera import Camera, backproject, lens_valid_mask, project
from endopipe.stages.depth.config import DepthConfig
from endopipe.stages.depth.view import INFERRED_DIR, VIEWS_DIR, frame_file
from endopipe.stages.ingest.view import IngestView


def consistent_views(
    depths: dict[int, np.ndarray],
    c2w: dict[int, np.ndarray],
    camera: Camera,
    neighbours: int,
    tolerance: float,
) -> dict[int, np.ndarray]:
    """Per frame (H, W) uint8: how many of its `neighbours` nearest frames (in frame order)
    see each depth pixel's surface point inside their lens, in front of them, with their own
    depth there within `tolerance` x its depth. 0 where the frame has no depth."""
    order = sorted(depths)
    lens = lens_valid_mask(camera)
    h, w = camera.height, camera.width
    counts: dict[int, np.ndarray] = {}
    for p, i in enumerate(order):
        d = depths[i]
        has = d > 0
        count = np.zeros((h, w), np.uint8)
        if has.any():
            points = backproject(camera, d, c2w[i])[has]
            for j in _nearest(order, p, neighbours):
                uv, z = project(camera, points, c2w[j])
                u = np.rint(uv[:, 0]).astype(np.int64)
                v = np.rint(uv[:, 1]).astype(np.int64)
                inside = (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
                inside[inside] &= lens[v[inside], u[inside]]
                theirs = np.zeros(len(z), np.float32)
                theirs[inside] = depths[j][v[inside], u[inside]]
                agree = (theirs > 0) & (np.abs(theirs - z) <= tolerance * np.abs(z))
                count[has] += agree.astype(np.uint8)
        counts[i] = count
    return counts


def _nearest(order: list[int], p: int, n: int) -> list[int]:
    """The n frames nearest position p in `order`, p itself left out (fewer at the ends)."""
    lo = max(0, min(p - n // 2, len(order) - 1 - n))
    return [order[q] for q in range(lo, min(len(order), lo + n + 1)) if q != p][:n]


@dataclass
class Support:
    """What the views maps found, in pixels over all frames, and per frame the pixels
    `seen_again_views` other views agree with."""

    seen_again: int
    one_view: int
    inferred: int
    extrapolated: int  # of `inferred`: past the radius the lens was fitted within
    seen_again_maps: dict[int, np.ndarray]


def write_support(
    out: Path,
    cfg: DepthConfig,
    ingest: IngestView,
    depths: dict[int, np.ndarray],
    c2w: dict[int, np.ndarray],
    camera: Camera,
    beyond_lens: np.ndarray,
    extrapolated: np.ndarray | None = None,
    still: bool = False,
) -> Support | None:
    """views/<i>.npy (uint8 agreeing views) and inferred/<i>.npy (bool) per frame; None when
    depth.support_frames is 0. A `still` camera saw every pixel from one place only: frames
    that agree there agree with the field's one guess, not with a second view, so no view
    counts (every depth rests on one view)."""
    if cfg.support_frames <= 0 or not depths:
        return None
    counts = (
        {i: np.zeros(d.shape, np.uint8) for i, d in depths.items()}
        if still
        else consistent_views(depths, c2w, camera, cfg.support_frames, cfg.support_tolerance)
    )
    for sub in (VIEWS_DIR, INFERRED_DIR):
        (out / sub).mkdir(exist_ok=True)
    fov = ingest.fov()
    seen = one = inferred_px = extrapolated_px = 0
    maps = {}
    for i, d in depths.items():
        has = (d > 0) & ~beyond_lens
        views = np.where(has, counts[i], 0).astype(np.uint8)
        inferred = has & (ingest.mask(i) <= 127)
        if fov is not None:
            inferred &= fov > 127
        if extrapolated is not None:
            extrapolated_px += int((has & extrapolated).sum())
            inferred |= has & extrapolated
        np.save(out / VIEWS_DIR / frame_file(i), views)
        np.save(out / INFERRED_DIR / frame_file(i), inferred)
        maps[i] = views >= cfg.seen_again_views
        seen += int(maps[i].sum())
        one += int((has & (counts[i] == 0)).sum())
        inferred_px += int(inferred.sum())
    return Support(seen, one, inferred_px, extrapolated_px, maps)
