"""recording/summary.json: each window's outcome, the verdict and the recording's scores, as
one model on both sides (written into the folder and its manifest, read back by the view).
Pydantic only: `endopipe status` reads it without numpy."""

from __future__ import annotations

from pydantic import Field

from endopipe.pipeline.stage import Summary


class LightScale(Summary):
    """What the light said about the path's scale (recording/summary.json)."""

    applied: bool
    reason: str = ""
    falloff: float | None = Field(None, description="log brightness per log depth, fitted")
    frames: int = 0
    drift_range: float | None = Field(
        None, description="Largest over smallest smoothed scale along the path (1: no drift)."
    )
    window_drift: float | None = Field(
        None, description="The same inside the window where it is largest."
    )


class WindowRow(Summary):
    """One window's outcome in the recording's summary."""

    name: str
    frames: int
    status: str
    reason: str = ""
    pose_verdict: str = ""
    registered: int | None = None
    depth_abs_rel: float | None = None  # median-scaled (a relative truth: affine-fitted)
    wall_s: float = 0.0


class SegmentAte(Summary):
    """One segment's trajectory against the truth, aligned on its own (segments are not tied
    to each other)."""

    segment: int
    keyframes: int
    percent_of_path: float


class RecordingSummary(Summary):
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
    ate_by_segment: list[SegmentAte] = []  # every segment's, each aligned on its own
    light_scale: LightScale | None = None  # the path's scale drift, measured from the light
    ate_as_joined_pct: float | None = None  # the ATE before the path was redrawn for it
    frames: int | None = None  # frames ingest judged (kept as keyframes, or dropped)
    frames_posed: int | None = None  # of them, posed and given depth (keyframes, registered)
    keyframes_doubtful: list[int] = []  # registered from a neighbour, away from their SfM pose
    # Depth of every posed frame with truth: "exact" truth is scored median-scaled, a "relative"
    # one (an affine proxy of depth, as C3VD's) after a least-squares scale and shift.
    depth_gt_kind: str | None = None
    depth_abs_rel_all_frames: float | None = None
    depth_abs_rel_keyframes: float | None = None  # the same over the keyframes alone
    # exact truth: one scale for each segment's frames instead of one a frame (2,000 pixels a frame)
    depth_abs_rel_one_scale: float | None = None
    depth_spearman_all_frames: float | None = None  # relative truth: rank correlation
    depth_coverage_all_frames: float | None = None  # share of the truth's pixels given a depth
    depth_frames_scored: int | None = None
    brightness_guess_abs_rel: float | None = None  # a guess from shading alone, same pixels
    mesh_frames: int | None = None  # keyframes fused into recording/mesh.ply (segment 0)
    chamfer_pct_radius: float | None = None  # the fused mesh against the ground-truth mesh
    off_seen_pct: float | None = None  # share of the mesh far from any surface a camera saw


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
