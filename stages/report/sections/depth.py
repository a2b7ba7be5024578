"""Depth: the accuracy under each protocol, ours against two guesses, the held-out image
quality, how the maps were rendered, previews and the preview video."""

from __future__ import annotations

from typing import TYPE_CHECKING

from endopipe.stages.report.figures import plot_per_frame
from endopipe.stages.report.images import video_uri
from endopipe.stages.report.kit import not_available, render
from endopipe.stages.report.load import CaseData
from endopipe.stages.report.sections.common import ReportInfo, heldout_image_scores
from endopipe.stages.report.sections.guesses import comparison
from endopipe.stages.report.sections.previews import depth_previews
from endopipe.stages.report.sections.scores import per_frame_series, score_table

if TYPE_CHECKING:
    from endopipe.stages.depth.summary import DepthSummary
    from endopipe.stages.depth.view import DepthMetrics

RENDERERS = {
    "baked": "the surface baked from the field once, then ray cast",
    "field": "the field itself, ray marched",
    "stereo": "no field: the rig's depth as ingest matched it (a stereo pair alone)",
}


def unknown_depth(s: DepthSummary) -> str | None:
    """The share of the lens's pixels without a depth, and why (None when not measured)."""
    unknown, hazy = s.unknown_share, s.hazy_share
    if unknown is None:
        return None
    why = "their rays found no surface"
    if hazy:
        why = f"{100 * hazy:.1f}% spread over no one surface, depth.max_spread"
        if unknown - hazy > 5e-4:
            why += "; the rest found none"
    return f"{100 * unknown:.1f}% of the lens's pixels ({why})"


def support_line(s: DepthSummary, dm: DepthMetrics | None) -> str | None:
    """What the views maps found (None when the stage wrote none), with ours on the
    pixels seen again and on the rest when there is a ground truth."""
    if s.seen_again_share is None:
        return None
    line = (
        f"{100 * s.seen_again_share:.1f}% of the lens's pixels have a depth nearby views agree "
        f"with, {100 * (s.one_view_share or 0):.1f}% one no other view confirms; "
        f"{100 * (s.inferred_share or 0):.1f}% are inferred (under their frame's own mask"
        + (
            f", or {100 * s.extrapolated_share:.1f}% past the radius the estimated lens was "
            "fitted within)"
            if s.extrapolated_share
            else ")"
        )
    )
    by = dm.by_support if dm is not None else None
    if by and "seen_again" in by and "rest" in by:
        a, b = by["seen_again"].abs_rel, by["rest"].abs_rel
        if a is not None and b is not None:
            name = "SSI-AbsRel" if dm.gt_kind == "relative" else "AbsRel"
            line += f"; {name} {a:.4f} where seen again, {b:.4f} on the rest"
    if s.truth_supervised:
        line += (
            f". The ground truth's depth ({s.truth_supervised}) also supervised the field: the "
            "scores say how closely the field follows it, not how right it is"
        )
    if s.one_viewpoint:
        line = (
            "The camera stood still: no pixel was seen from two places. Every depth here is "
            "relative (from shading, smoothness and the field's fit over time, in units where "
            "the typical distance is 1) and weaker than depth measured by parallax. " + line
        )
    return line


def renderer(s: DepthSummary) -> str:
    """The renderer's name, and what it does when the report knows it."""
    return f"{s.renderer}: {RENDERERS[s.renderer]}" if s.renderer in RENDERERS else s.renderer


#: Our metric depth and a metric truth a constant apart by more than this: said, with why.
SCALE_APART = 0.10


def scale_line(dm: DepthMetrics | None, metric: bool) -> str | None:
    """When our depth is metric and one scale for the sequence still moves it by more than
    SCALE_APART to the truth: the ratio, and what a constant ratio means."""
    if not metric or dm is None or dm.unscaled is None or dm.sequence_scaled is None:
        return None
    scale = dm.sequence_scaled.scale
    if scale is None or abs(scale - 1.0) <= SCALE_APART:
        return None
    return (
        f"Our depth is metric, yet the truth is {scale:.3f} times it (one scale for the "
        "sequence). A constant ratio is a difference of calibration or units, not of shape: "
        "the truth made with another focal length or baseline than ours (a release's stereo "
        "depth from its own calibration), or stated in other units. The scaled scores measure "
        "the shape; the unscaled ones this ratio. Check the truth's units and calibration "
        "before reading them as our error."
    )


def section_depth(data: CaseData, info: ReportInfo) -> str | None:
    if data.depth is None:
        if "depth" in data.view_errors:
            return not_available(f"05_depth unreadable: {data.view_errors['depth']}")
        return None
    dm, s, cfg = data.depth_metrics, data.depth_summary, data.cfg
    psnr, ssim = heldout_image_scores(data)
    table = per_frame = None
    if dm is not None:
        table = score_table(dm.median_scaled, dm.sequence_scaled, dm.affine_invariant, data.units)
        series = per_frame_series(dm.per_frame)
        per_frame = plot_per_frame(series) if series else None
    no_metrics = (
        "no ground truth to evaluate against"
        if info.gt_kind == "none"
        else "05_depth/metrics.json is missing"
    )
    preview = data.depth.preview_path
    video_mb = preview.stat().st_size / 2**20 if preview.is_file() else None
    show_video = video_mb is not None and cfg.include_video
    return render(
        "sections/depth.html.j2",
        dm=dm,
        table=table,
        comparison=comparison(dm) if dm is not None else None,
        psnr=psnr,
        ssim=ssim,
        per_frame=per_frame,
        no_metrics=no_metrics,
        scale_said=scale_line(dm, data.poses is not None and data.poses.metric),
        s=s,
        renderer=renderer(s) if s is not None else "",
        unknown=unknown_depth(s) if s is not None else None,
        support=support_line(s, dm) if s is not None else None,
        previews=depth_previews(data),
        show_video=show_video,
        video_src=video_uri(preview) if show_video and video_mb <= cfg.max_video_mb else None,
        video_mb=video_mb,
        max_video_mb=cfg.max_video_mb,
        preview_path=str(preview),
    )
