"""recording/summary.json: each window's outcome, the verdict and the recording's scores."""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel

from endopipe.commands.batch.rows import CaseRow
from endopipe.commands.recording.join import Joined
from endopipe.commands.recording.light_scale import LightScale
from endopipe.commands.recording.windows import WindowPlan


class WindowRow(BaseModel):
    """One window's outcome in the recording's summary."""

    name: str
    frames: int
    status: str
    reason: str = ""
    pose_verdict: str = ""
    registered: int | None = None
    depth_abs_rel: float | None = None  # median-scaled (a relative truth: affine-fitted)
    wall_s: float = 0.0


class RecordingSummary(BaseModel):
    """recording/summary.json: the windows, the junctions, the joined trajectory's scores."""

    keyframes: int
    windows: list[WindowRow]
    one_sfm: bool = False  # posed by one SfM over the recording, its windows cut from it
    segments: int
    posed_keyframes: int
    verdict: str  # ok | doubtful
    reasons: list[str] = []
    ate_percent_of_path: float | None = None  # joined trajectory against the truth (segment 0)
    ate_frames: int | None = None
    light_scale: LightScale | None = None  # the path's scale drift, measured from the light
    ate_as_joined_pct: float | None = None  # the ATE before the path was redrawn for it
    frames: int | None = None  # frames from segment 0's first keyframe to its last
    frames_posed: int | None = None  # of them, posed (keyframes, and frames registered)
    # Depth of every posed frame with truth: "exact" truth is scored median-scaled, a "relative"
    # one (an affine proxy of depth, as C3VD's) after a least-squares scale and shift.
    depth_gt_kind: str | None = None
    depth_abs_rel_all_frames: float | None = None
    depth_abs_rel_keyframes: float | None = None  # the same over the keyframes alone
    depth_spearman_all_frames: float | None = None  # relative truth: rank correlation
    depth_coverage_all_frames: float | None = None  # share of the truth's pixels given a depth
    depth_frames_scored: int | None = None
    brightness_guess_abs_rel: float | None = None  # a guess from shading alone, same pixels
    mesh_frames: int | None = None  # keyframes fused into recording/mesh.ply (segment 0)
    chamfer_pct_radius: float | None = None  # the fused mesh against the ground-truth mesh
    off_seen_pct: float | None = None  # share of the mesh far from any surface a camera saw


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
    return RecordingSummary(
        keyframes=len({i for w in plan.windows for i in w}),
        windows=windows,
        segments=joined.segments,
        posed_keyframes=len(joined.frames),
        verdict="doubtful" if reasons else "ok",
        reasons=reasons,
        ate_percent_of_path=ate,
        ate_frames=frames,
    )


def joined_ate(joined: Joined, truth: list[np.ndarray] | None) -> tuple[float | None, int | None]:
    """The first segment's ATE (% of the path) against the truth and the keyframes it is over."""
    from endopipe.stages.metrics.depth import pose_metrics

    if truth is None:
        return None, None
    est = {f.source_index: np.array(f.c2w) for f in joined.frames if f.segment == 0}
    gt = {i: truth[i] for i in est if i < len(truth)}
    if len(gt) < 3:
        return None, None
    m = pose_metrics(est, gt)
    return m["ate_percent_of_path"], int(m["frames"])


def light_line(summary: RecordingSummary) -> str:
    """One line on the scale drift the light measured, for the terminal and the report."""
    light = summary.light_scale
    if light is None:
        return "scale from the light: not measured"
    if not light.applied:
        return f"scale from the light: path left as joined ({light.reason})"
    before = (
        f"; ATE as joined {summary.ate_as_joined_pct:.2f}% of the path"
        if summary.ate_as_joined_pct is not None
        else ""
    )
    return (
        f"scale from the light: the joined path drifted {light.drift_range:.2f}x in scale over "
        f"{light.frames} keyframes, redrawn without it (falloff {light.falloff:.2f}){before}; "
        "assumes a fixed exposure (--no-light-scale for a scope with auto-exposure)"
    )


def _int(value: float | None) -> int | None:
    return None if value is None else int(value)
