"""The report's plots (matplotlib, no pyplot: no global state, no GUI backend), as data URIs."""

from __future__ import annotations

import base64
import io
from dataclasses import dataclass

import cv2
import numpy as np

from endopipe.stages.report.images import image_uri

NEAREST = {"interpolation": "nearest", "interpolation_stage": "rgba"}


@dataclass
class Curve:
    """The lumen's centre line: samples, radius and arc length at each, the cameras' span."""

    points: np.ndarray  # (N, 3)
    radius: np.ndarray  # (N,)
    arclength: np.ndarray  # (N,)
    camera_span: tuple[float, float] | None = None


@dataclass
class PreviewRow:
    """One row of the depth preview: a frame, its depth, its truth and the error between."""

    index: int
    source_index: int | None
    rgb: np.ndarray | None
    depth: np.ndarray  # as estimated (scaled to GT by its median ratio when GT exists)
    gt: np.ndarray | None
    error: np.ndarray | None  # abs-rel error, NaN where not evaluated
    scale: float | None
    inside: np.ndarray | None = None  # the frame's mask (bool): where a depth is asked for
    views: np.ndarray | None = None  # other nearby views that see this surface (uint8 count)
    inferred: np.ndarray | None = None  # depth under the frame's own mask (bool)


def _figure(width: float, height: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=100)


def figure_uri(fig, fmt_: str = "png", quality: int = 88) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi, facecolor="white")  # laid out by tight_layout
    if fmt_ == "png":
        return f"data:image/png;base64,{base64.b64encode(buf.getvalue()).decode()}"
    img = cv2.imdecode(np.frombuffer(buf.getvalue(), np.uint8), cv2.IMREAD_COLOR)
    return image_uri(cv2.cvtColor(img, cv2.COLOR_BGR2RGB), "jpg", quality)


def plot_trajectory(
    centres: np.ndarray,
    views: np.ndarray,
    centerline: Curve | None,
    gt: np.ndarray | None,
    units: str,
    doubtful: np.ndarray | None = None,
) -> str:
    """Three panels: 3D view, the plane of the path's two main axes, radius along the curve.
    `doubtful`: a mask over `centres`, the poses the verdict doubts (red crosses)."""
    fig = _figure(13.0, 4.2)
    ax3 = fig.add_subplot(1, 3, 1, projection="3d")
    ax2 = fig.add_subplot(1, 3, 2)
    ax_r = fig.add_subplot(1, 3, 3)
    pts = [centres]
    curve = radius = arclen = None
    if centerline is not None and len(centerline.points):
        curve = np.asarray(centerline.points, dtype=np.float64).reshape(-1, 3)
        radius = np.asarray(centerline.radius, dtype=np.float64)
        arclen = np.asarray(centerline.arclength, dtype=np.float64)
        pts.append(curve)
    if gt is not None:
        pts.append(gt)
    allp = np.concatenate(pts)
    mean = allp.mean(0)
    _, _, vt = np.linalg.svd(allp - mean, full_matrices=False)
    if vt.shape[0] < 3:
        vt = np.eye(3)
    scale = float(np.ptp(allp, axis=0).max()) or 1.0
    colours = np.linspace(0, 1, len(centres))

    if gt is not None:
        ax3.plot(*gt.T, color="0.55", lw=1.2, ls="--", label="ground truth")
    if curve is not None:
        ax3.plot(*curve.T, color="#c0392b", lw=2.0, label="centre line")
    ax3.plot(*centres.T, color="#1f4e79", lw=1.0, alpha=0.6)
    ax3.scatter(*centres.T, c=colours, cmap="viridis", s=10, depthshade=False, label="cameras")
    bad = np.asarray(doubtful, bool) if doubtful is not None else np.zeros(len(centres), bool)
    if bad.any():
        ax3.scatter(*centres[bad].T, marker="x", color="#c0392b", s=28, label="doubtful pose")
    step = max(1, len(centres) // 12)
    q = centres[::step]
    d = views[::step] * 0.06 * scale
    ax3.quiver(*q.T, *d.T, color="#2c3e50", lw=0.8, arrow_length_ratio=0.25)
    mid = (allp.max(0) + allp.min(0)) / 2
    half = 0.55 * scale
    ax3.set_xlim(mid[0] - half, mid[0] + half)
    ax3.set_ylim(mid[1] - half, mid[1] + half)
    ax3.set_zlim(mid[2] - half, mid[2] + half)
    ax3.set_box_aspect((1, 1, 1))
    ax3.set_xlabel(f"x ({units})", fontsize=8)
    ax3.set_ylabel(f"y ({units})", fontsize=8)
    ax3.set_zlabel(f"z ({units})", fontsize=8)
    ax3.tick_params(labelsize=7)
    ax3.legend(fontsize=7, loc="upper left")
    ax3.set_title("3D trajectory", fontsize=10)

    def plane(p: np.ndarray) -> np.ndarray:
        return (p - mean) @ vt[:2].T

    if gt is not None:
        g2 = plane(gt)
        ax2.plot(g2[:, 0], g2[:, 1], color="0.55", ls="--", lw=1.2, label="ground truth")
    if curve is not None:
        c2 = plane(curve)
        ax2.plot(c2[:, 0], c2[:, 1], color="#c0392b", lw=2.0, label="centre line")
        if radius is not None and len(radius) == len(curve) and len(curve) > 2:
            t = np.gradient(c2, axis=0)
            n = np.stack([-t[:, 1], t[:, 0]], 1)
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            for sgn in (1, -1):
                w = c2 + sgn * radius[:, None] * n
                ax2.plot(w[:, 0], w[:, 1], color="#c0392b", lw=0.8, alpha=0.5)
            ax2.plot([], [], color="#c0392b", lw=0.8, alpha=0.5, label="centre line ± radius")
    p2 = plane(centres)
    ax2.plot(p2[:, 0], p2[:, 1], color="#1f4e79", lw=1.0, alpha=0.6)
    sc = ax2.scatter(p2[:, 0], p2[:, 1], c=colours, cmap="viridis", s=12, zorder=3, label="cameras")
    if bad.any():
        ax2.scatter(*p2[bad].T, marker="x", color="#c0392b", s=34, zorder=4, label="doubtful pose")
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.set_xlabel(f"main axis ({units})", fontsize=8)
    ax2.set_ylabel(f"second axis ({units})", fontsize=8)
    ax2.tick_params(labelsize=7)
    ax2.legend(fontsize=7, loc="best")
    ax2.set_title("Plane of the path (principal axes)", fontsize=10)
    cb = fig.colorbar(sc, ax=ax2, fraction=0.046, pad=0.02)
    cb.set_label("frame order", fontsize=7)
    cb.set_ticks([])

    if radius is not None and len(radius) and arclen is not None and len(arclen) == len(radius):
        ax_r.plot(arclen, radius, color="#c0392b", lw=1.5)
        span = centerline.camera_span if centerline else None
        if span and len(span) == 2:
            ax_r.axvspan(span[0], span[1], color="#1f4e79", alpha=0.08, label="camera span")
            ax_r.legend(fontsize=7)
        ax_r.set_xlabel(f"arc length ({units})", fontsize=8)
        ax_r.set_ylabel(f"radius ({units})", fontsize=8)
        ax_r.set_ylim(bottom=0)
        ax_r.set_title("Lumen radius along the centre line", fontsize=10)
    else:
        ax_r.text(0.5, 0.5, "no radius profile", ha="center", va="center", color="0.5")
        ax_r.set_axis_off()
    ax_r.tick_params(labelsize=7)
    ax_r.grid(alpha=0.3)
    fig.tight_layout()
    return figure_uri(fig)


def plot_per_frame(series: dict[str, tuple[list, list]], metric: str = "AbsRel") -> str:
    fig = _figure(11.0, 2.4)
    ax = fig.add_subplot(1, 1, 1)
    for label, (x, y) in series.items():
        y_arr = np.asarray(y, dtype=np.float64)
        ax.plot(
            x, y_arr, marker="o", ms=2.5, lw=1.0, label=f"{label} (mean {np.nanmean(y_arr):.3g})"
        )
    ax.set_xlabel("frame", fontsize=8)
    ax.set_ylabel(metric, fontsize=8)
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return figure_uri(fig)


def _paint(ax, where: np.ndarray, rgb: tuple[float, float, float]) -> None:
    """Cover the pixels `where` with one flat colour, over what the axes already show."""
    if where.any():
        overlay = np.zeros((*where.shape, 4), np.float32)
        overlay[where] = (*rgb, 1.0)
        ax.imshow(overlay, **NEAREST)


def plot_depth_preview(rows: list[PreviewRow], units: str, error_max: float) -> str:
    from matplotlib import colormaps

    has_gt = any(r.gt is not None for r in rows)
    has_views = any(r.views is not None for r in rows)
    ncols = (4 if has_gt else 2) + has_views
    h, w = rows[0].depth.shape[:2]
    tile_w = 3.1
    fig = _figure(tile_w * ncols + 0.8, len(rows) * tile_w * h / w + 0.5)
    from endopipe.stages.depth.preview import DEPTH_CMAP, ERROR_CMAP, NO_DEPTH

    # as in preview.mp4: NO_DEPTH grey = a hole in ours, black = nothing asked (outside, no GT)
    grey = tuple(c / 255 for c in NO_DEPTH)
    turbo = colormaps[DEPTH_CMAP].with_extremes(bad=grey)
    turbo_gt = colormaps[DEPTH_CMAP].with_extremes(bad="black")  # no truth is no hole of ours
    inferno = colormaps[ERROR_CMAP].with_extremes(bad="black")
    for r_i, row in enumerate(rows):
        valid = (row.depth > 0) & np.isfinite(row.depth)
        ref = row.gt[row.gt > 0] if row.gt is not None and (row.gt > 0).any() else None
        ref = ref if ref is not None else row.depth[valid]
        lo, hi = np.percentile(ref, [2, 98]) if ref.size else (0.0, 1.0)
        hi = hi if hi > lo else lo + 1e-6
        axes = [fig.add_subplot(len(rows), ncols, r_i * ncols + c + 1) for c in range(ncols)]
        src = f", source {row.source_index}" if row.source_index is not None else ""
        if row.rgb is not None:
            axes[0].imshow(row.rgb, **NEAREST)
        else:
            axes[0].text(0.5, 0.5, "no image", ha="center", va="center", color="0.5")
        axes[0].set_title(f"frame {row.index}{src}", fontsize=8)
        label = "depth (median-scaled to GT)" if row.scale is not None else "estimated depth"
        im = axes[1].imshow(
            np.ma.masked_where(~valid, row.depth), cmap=turbo, vmin=lo, vmax=hi, **NEAREST
        )
        inside = row.inside if row.inside is not None else np.ones_like(valid)
        _paint(axes[1], ~inside, (0.0, 0.0, 0.0))
        holes = 1 - (valid & inside).sum() / max(int(inside.sum()), 1)
        axes[1].set_title(f"{label}\ngrey = no depth ({100 * holes:.0f}% of view)", fontsize=8)
        cb = fig.colorbar(im, ax=axes[1], fraction=0.046, pad=0.02)
        cb.ax.tick_params(labelsize=6)
        cb.set_label(units, fontsize=6)
        if has_gt:
            if row.gt is not None:
                im = axes[2].imshow(
                    np.ma.masked_where(row.gt <= 0, row.gt),
                    cmap=turbo_gt,
                    vmin=lo,
                    vmax=hi,
                    **NEAREST,
                )
                cb = fig.colorbar(im, ax=axes[2], fraction=0.046, pad=0.02)
                cb.ax.tick_params(labelsize=6)
                axes[2].set_title("ground-truth depth", fontsize=8)
            else:
                axes[2].text(0.5, 0.5, "no GT for this frame", ha="center", va="center")
            if row.error is not None:
                err = np.ma.masked_invalid(row.error)
                im = axes[3].imshow(err, cmap=inferno, vmin=0, vmax=error_max, **NEAREST)
                if row.gt is not None:
                    _paint(axes[3], (row.gt > 0) & inside & ~valid, grey)
                cb = fig.colorbar(im, ax=axes[3], fraction=0.046, pad=0.02)
                cb.ax.tick_params(labelsize=6)
                axes[3].set_title(f"abs-rel error (mean {np.nanmean(row.error):.3f})", fontsize=8)
            else:
                axes[3].text(0.5, 0.5, "not evaluated", ha="center", va="center", color="0.5")
        if has_views:
            _views_tile(fig, axes[-1], row, valid, inside, grey)
        for ax in axes:
            ax.set_xticks([])
            ax.set_yticks([])
    fig.tight_layout()
    return figure_uri(fig, "jpg", 90)


def _views_tile(fig, ax, row: PreviewRow, valid, inside, grey) -> None:
    """The views map: other views that see each depth pixel's surface (viridis), no depth
    grey, inferred magenta."""
    from matplotlib import colormaps

    if row.views is None:
        ax.text(0.5, 0.5, "no views map", ha="center", va="center", color="0.5")
        return
    cmap = colormaps["viridis"].with_extremes(bad=grey)
    shown = np.ma.masked_where(~valid, row.views.astype(np.float32))
    im = ax.imshow(shown, cmap=cmap, vmin=0.0, vmax=max(float(row.views.max()), 1.0), **NEAREST)
    _paint(ax, ~inside if row.inferred is None else ~inside & ~row.inferred, (0.0, 0.0, 0.0))
    if row.inferred is not None:
        _paint(ax, row.inferred, (1.0, 0.0, 1.0))
    cb = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02)
    cb.ax.tick_params(labelsize=6)
    alone = float((row.views == 0)[valid].mean()) if valid.any() else 0.0
    ax.set_title(
        f"other views that see it\n{100 * alone:.0f}% of depth seen by no other; "
        "magenta = inferred",
        fontsize=8,
    )
