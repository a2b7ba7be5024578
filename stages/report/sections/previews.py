"""The depth previews: a few frames, each as image | depth | ground truth | error, with the
depth scaled to the truth the way the evaluation scales it."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from endopipe.stages.report.figures import PreviewRow, plot_depth_preview
from endopipe.stages.report.kit import one_line
from endopipe.stages.report.load import CaseData
from endopipe.stages.report.sections.common import Figure


@dataclass
class Previews:
    """What the previews part shows: the figure (None when no row could be drawn), the frames
    left out and why, and whether there were depth maps at all."""

    figure: Figure | None = None
    wide: bool = False
    problems: list[str] = field(default_factory=list)
    no_maps: bool = False


def pick_frames(indices: list[int], count: int) -> list[int]:
    if count <= 0 or not indices:
        return []
    if len(indices) <= count:
        return list(indices)
    pos = np.linspace(0, len(indices) - 1, count).round().astype(int)
    return [indices[p] for p in dict.fromkeys(pos.tolist())]


def preview_row(data: CaseData, index: int) -> PreviewRow:
    """Frame `index`: image, depth (median-scaled to the truth when there is one), truth, and
    the abs-rel error on pixels the frame's mask keeps."""
    from endopipe.stages.depth.preview import scaled_error
    from endopipe.stages.io.ground_truth import depth_of_frame

    depth = np.asarray(data.depth.depth(index), np.float32)
    h, w = depth.shape[:2]
    ingest = data.ingest
    rgb = mask = entry = None
    if ingest is not None and ingest.has_frame(index):
        entry = ingest.frame(index)
        img = ingest.image(index)
        rgb = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
        m = ingest.mask(index)
        if m is not None:
            mask = cv2.resize(m, (w, h), interpolation=cv2.INTER_NEAREST) > 127
    src = entry.source_index if entry is not None else None
    gt_depth = error = scale = None
    g = depth_of_frame(data.ground_truth(), entry) if entry is not None else None
    if g is not None:
        g = np.asarray(g, dtype=np.float32)
        if g.shape != depth.shape:
            g = cv2.resize(g, (w, h), interpolation=cv2.INTER_NEAREST)
        gt_depth = g
        valid = (g > 0) & (depth > 0) & np.isfinite(depth)
        if mask is not None:
            valid &= mask
        if valid.sum() > 10:
            error, scale, _ = scaled_error(depth, g, valid)
    shown = depth * scale if scale is not None else depth
    views, inferred = data.depth.views(index), data.depth.inferred(index)
    if views is not None and views.shape != depth.shape:
        views = inferred = None
    return PreviewRow(index, src, rgb, shown, gt_depth, error, scale, mask, views, inferred)


def _shrink_row(row: PreviewRow, width: int) -> PreviewRow:
    h, w = row.depth.shape[:2]
    size = (width, max(1, round(h * width / w)))

    def near(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else cv2.resize(a, size, interpolation=cv2.INTER_NEAREST)

    rgb = None if row.rgb is None else cv2.resize(row.rgb, size, interpolation=cv2.INTER_AREA)

    def near_mask(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else near(a.astype(np.uint8)) > 0

    return PreviewRow(
        row.index,
        row.source_index,
        rgb,
        near(row.depth),
        near(row.gt),
        near(row.error),
        row.scale,
        near_mask(row.inside),
        near(row.views),
        near_mask(row.inferred),
    )


def depth_previews(data: CaseData) -> Previews:
    """The previews of `max_preview_frames` frames spread over the sequence; an unreadable
    map costs its row (named in `problems`)."""
    cfg = data.cfg
    picks = pick_frames(sorted(data.depth.indices), cfg.max_preview_frames)
    if not picks:
        return Previews(no_maps=True)
    rows, bad = [], []
    for i in picks:
        try:
            row = preview_row(data, i)
        except Exception as e:  # noqa: BLE001 - one unreadable map costs one row
            bad.append(f"frame {i}: {one_line(e)}")
            continue
        if row.depth.ndim != 2:
            bad.append(f"frame {i}: depth map of shape {row.depth.shape}")
            continue
        rows.append(row)
    if not rows:
        return Previews(problems=bad)
    rows = [r for r in rows if r.depth.shape == rows[0].depth.shape]
    if cfg.preview_width and rows[0].depth.shape[1] > cfg.preview_width:
        rows = [_shrink_row(r, cfg.preview_width) for r in rows]
    uri = plot_depth_preview(rows, data.units, cfg.error_max)
    caption = "Depth previews: RGB | depth (turbo colour map, near = blue; grey = no depth)"
    has_gt = any(r.gt is not None for r in rows)
    if has_gt:  # four columns
        caption += (
            " | ground truth (same colour scale) | abs-rel error after per-frame median "
            f"scaling (0 to {cfg.error_max:g}; grey = ground truth but no depth)"
        )
    if any(r.views is not None for r in rows):
        caption += (
            " | views: how many nearby frames see this pixel's surface point where their own "
            "depth puts it (a count of observations, not of accuracy; magenta = under the "
            "frame's own mask, a highlight or a tool: the field's surface there is inferred, "
            "not observed)"
        )
    return Previews(Figure(uri, caption + "."), wide=has_gt, problems=bad)
