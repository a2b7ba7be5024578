"""The camera trajectory and the centre line: the poses' verdict, the trajectory over the lumen
prior, and the poses' and centre line's figures."""

from __future__ import annotations

from typing import Any

import numpy as np

from endopipe.stages.poses.verdict import PoseVerdict
from endopipe.stages.report.figures import Curve, plot_trajectory
from endopipe.stages.report.images import file_image_uri
from endopipe.stages.report.kit import render
from endopipe.stages.report.load import CaseData
from endopipe.stages.report.sections.common import Figure, ReportInfo
from endopipe.stages.report.sections.pose_verdict import VerdictBlock


def gt_centres(data: CaseData, ids: list[int]) -> np.ndarray | None:
    """Ground-truth camera centres of the registered frames, when poses are in the GT frame."""
    from endopipe.stages.io.ground_truth import poses_by_frame

    if data.poses is None or not data.poses.in_gt_frame or data.ingest is None:
        return None
    truth = poses_by_frame(data.ground_truth(), data.ingest.frames)
    if truth is None or any(i not in truth for i in ids):
        return None
    return np.reshape([truth[i][:3, 3] for i in ids], (-1, 3))


def centre_line(data: CaseData) -> Curve | None:
    cl = data.centerline
    if cl is None:
        return None
    return Curve(cl.points, cl.radius, cl.arclength, cl.file.camera_span)


def unregistered_frames(poses: Any) -> str:
    """Frames without a pose, as ranges: '4, 9-11'."""
    runs: list[str] = []
    for i in (f.index for f in poses.file.frames if not f.registered):
        if runs and runs[-1].split("-")[-1] == str(i - 1):
            runs[-1] = f"{runs[-1].split('-')[0]}-{i}"
        else:
            runs.append(str(i))
    return ", ".join(runs) or "none"


def trajectory(data: CaseData, verdict: PoseVerdict | None) -> Figure | None:
    """The registered cameras over the centre line, doubtful ones marked (None: none)."""
    poses = data.poses
    ids = poses.registered
    if not ids:
        return None
    views = np.reshape([poses.c2w[i][:3, 2] for i in ids], (-1, 3))
    try:
        gt = gt_centres(data, ids)
    except Exception:  # noqa: BLE001 - GT overlay is optional
        gt = None
    flagged = {f.index for f in verdict.doubtful()} if verdict is not None else set()
    doubtful = np.array([i in flagged for i in ids]) if flagged else None
    uri = plot_trajectory(poses.centres(), views, centre_line(data), gt, data.units, doubtful)
    caption = (
        "Camera centres (coloured by frame order, arrows: viewing direction) and the "
        "lumen centre line with its radius"
        + ("; dashed: ground-truth trajectory" if gt is not None else "")
        + ("; red crosses: doubtful poses" if doubtful is not None else "")
        + "."
    )
    return Figure(uri, caption)


def section_poses(data: CaseData, info: ReportInfo) -> str | None:
    poses = data.poses
    verdict = data.pose_verdict() if poses is not None else None
    pos, cl = data.poses_summary, data.centerline_summary
    if poses is None and pos is None and cl is None:
        return None
    plot = None
    if data.centerline is not None:
        plot = file_image_uri(data.centerline.plot_path, 1100)
    unregistered = None
    if pos is not None:
        unregistered = unregistered_frames(poses) if poses else pos.unregistered or "none"
    return render(
        "sections/poses.html.j2",
        has_poses=poses is not None,
        verdict=VerdictBlock(verdict, data.verdict_error),
        trajectory=trajectory(data, verdict) if poses is not None else None,
        pos=pos,
        unregistered=unregistered,
        cl=cl,
        plot=plot,
    )
