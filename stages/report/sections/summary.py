"""The first screen: the case in cards (frames, registered, scale, ground truth, headline
scores, the poses' verdict), what a reader must not miss, and the case's facts."""

from __future__ import annotations

from endopipe.stages.report.kit import render
from endopipe.stages.report.load import CaseData
from endopipe.stages.report.sections.common import ReportInfo, heldout_image_scores, number
from endopipe.stages.report.sections.guesses import verdicts
from endopipe.stages.report.sections.pose_verdict import VerdictBlock

#: The ground truth's kind as a badge: (text, badge kind).
GT_BADGES = {
    "exact": ("exact", "ok"),
    "pseudo": ("pseudo", "warn"),
    "none": ("none", "muted"),
}
GT_HINTS = {"pseudo": "e.g. stereo-derived", "relative": "depth up to scale and shift"}


def section_summary(data: CaseData, info: ReportInfo) -> str:
    ing, pos = data.ingest_summary, data.poses_summary
    ingest, poses = data.ingest, data.poses
    n_frames = (len(ingest.frames) if ingest is not None else 0) or (ing.kept if ing else None)
    registered = total = None
    if poses is not None:
        total, registered = len(poses.file.frames), len(poses.registered)
    elif pos is not None:
        registered, total = pos.registered, pos.total
    dm = data.depth_metrics
    median = dm.median_scaled if dm is not None else None
    affine = dm.affine_invariant if dm is not None else None
    coverage = median.coverage if median is not None else None
    if coverage is None and affine is not None:
        coverage = affine.coverage
    mm = data.mesh_metrics
    verdict = data.pose_verdict() if poses is not None else None
    gt = info.gt_kind
    metric = poses.metric if poses is not None else (pos.metric if pos else None)
    # metric depth against an exact truth: its own error, no scale fitted, is the one to read
    unscaled = dm.unscaled if dm is not None and metric and gt == "exact" else None
    gt_dir = data.gt_dir()
    dropped = None
    if ing is not None and ing.dropped:
        dropped = ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in ing.dropped.items() if v)
    camera = None
    if poses is not None:
        cams = poses.file
        camera = (
            f"{cams.model} {cams.width}×{cams.height}, fx {cams.fx:.1f}, fy {cams.fy:.1f}, "
            f"cx {cams.cx:.1f}, cy {cams.cy:.1f} px"
        )
    return render(
        "sections/summary.html.j2",
        case=data.case,
        case_name=data.case.name if data.case else data.case_dir.name,
        ing=ing,
        pos=pos,
        n_frames=n_frames,
        registered=registered,
        total=total,
        metric=metric,
        unscaled=unscaled,
        gt=gt,
        gt_badge=GT_BADGES.get(gt, (gt, "muted")),
        gt_hint=GT_HINTS.get(gt, ""),
        gt_dir=str(gt_dir) if gt_dir else None,
        gt_dataset=getattr(data.ground_truth(), "dataset", "") if gt != "none" else "",
        median=median,
        affine=affine,
        coverage=number(coverage),
        chamfer=mm.chamfer if mm is not None else None,
        fscore=mm.fscore if mm is not None else None,
        tau=mm.threshold if mm is not None else None,
        psnr=heldout_image_scores(data)[0],
        verdict=VerdictBlock(verdict) if verdict is not None else None,
        guess_verdicts=verdicts(dm) if dm is not None else [],
        resolution=f"{ingest.width} × {ingest.height} px" if ingest is not None else None,
        dropped=dropped,
        camera=camera,
        pose_source=poses.file.source if poses is not None else None,
        units=data.units,
    )
