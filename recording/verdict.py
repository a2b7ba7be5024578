"""The recording's verdict and its trajectory's error: doubtful when a window failed or is
doubtful or the chain broke; the ATE of the first segment against the truth, when there is one."""

from __future__ import annotations

import numpy as np

from endopipe.jobs.rows import CaseRow
from endopipe.recording.join import Joined
from endopipe.recording.summary import RecordingSummary, SegmentAte, WindowRow
from endopipe.recording.windows import WindowPlan


def summarise(
    plan: WindowPlan, rows: list[CaseRow], joined: Joined, truth: list[np.ndarray] | None
) -> RecordingSummary:
    """The recording's verdict: doubtful when a window failed or is doubtful, or the chain
    broke; the ATE of the first segment against the truth, when there is one."""
    windows = [
        WindowRow(
            name=row.case,
            frames=len(frames),
            status=row.status,
            reason=row.reason,
            pose_verdict=row.pose_verdict,
            registered=_int(row.metrics.get("poses.registered")),
            depth_abs_rel=row.metrics.get(
                "depth.median_scaled.abs_rel", row.metrics.get("depth.affine_invariant.abs_rel")
            ),
            wall_s=row.wall_s,
        )
        for row, frames in zip(rows, plan.windows, strict=True)
    ]
    reasons = [f"{w.name} failed: {w.reason}" for w in windows if w.status != "ok"]
    reasons += [f"{w.name}: poses doubtful" for w in windows if w.pose_verdict == "doubtful"]
    reasons += [f"{j.a}-{j.b} not joined: {j.reason}" for j in joined.junctions if not j.joined]
    ate, frames = joined_ate(joined, truth)
    by_segment = []
    for k in range(joined.segments):
        pct, n = joined_ate(joined, truth, k)
        if pct is not None and n is not None:
            by_segment.append(SegmentAte(segment=k, keyframes=n, percent_of_path=pct))
    return RecordingSummary(
        ate_by_segment=by_segment,
        keyframes=len({i for w in plan.windows for i in w}),
        windows=windows,
        segments=joined.segments,
        posed_keyframes=len(joined.frames),
        verdict="doubtful" if reasons else "ok",
        reasons=reasons,
        ate_percent_of_path=ate,
        ate_frames=frames,
    )


def joined_ate(
    joined: Joined, truth: list[np.ndarray] | None, segment: int = 0
) -> tuple[float | None, int | None]:
    """A segment's ATE (% of its path, aligned on its own) against the truth and the keyframes
    it is over."""
    from endopipe.stages.metrics.depth import pose_metrics

    if truth is None:
        return None, None
    est = {f.source_index: np.array(f.c2w) for f in joined.frames if f.segment == segment}
    gt = {i: truth[i] for i in est if i < len(truth)}
    if len(gt) < 3:
        return None, None
    m = pose_metrics(est, gt)
    return m["ate_percent_of_path"], int(m["frames"])


def _int(value: float | None) -> int | None:
    return None if value is None else int(value)
