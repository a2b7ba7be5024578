"""What a batch job gets and gives back: small, picklable pydantic models."""

from __future__ import annotations

import math
import platform
from typing import Any, Literal

from pydantic import BaseModel, Field


class CaseTask(BaseModel):
    """Everything one case needs, small and picklable (configs are resolved JSON)."""

    name: str
    input: str
    reader: str
    workdir: str
    configs: dict[str, dict[str, Any]]
    until: str | None = None
    intrinsics: str | None = None  # intrinsics.json for the input's frames (--intrinsics)
    right: str | None = None  # the right eye's frames (--right)
    baseline_mm: float | None = None  # their baseline (--baseline-mm)
    depth_prior: str | None = None  # depth maps made elsewhere (--depth-prior)
    from_stage: str | None = None  # re-run from this stage (--from), fresh or not
    force: bool = False  # ignore the cache (--force)
    threads: int | None = None
    check_only: bool = False  # only report whether every stage is already fresh


class CaseRow(BaseModel):
    """One line of batch.csv: how a case went. Built by the case function, never raised."""

    case: str
    status: Literal["ok", "failed", "pending"]
    reader: str
    gt_kind: str = ""  # exact | pseudo | "" (no ground truth)
    stages_ran: list[str] = []
    stages_cached: list[str] = []
    failed_stage: str | None = None
    reason: str = ""
    # wall_s: the wall time of the run(s) that made the case's current outputs, kept when a
    # re-run finds them cached (for a failed case: this batch's time on it). this_batch_s:
    # this batch's time on the case, near 0 when everything was cached.
    wall_s: float = 0.0
    this_batch_s: float = 0.0
    compute_s: float = 0.0  # sum of the stages' own wall times (from their manifests)
    peak_rss_mb: float = 0.0  # the largest stage peak (from their manifests)
    # the poses' verdict (02_poses/verdict.json; empty for a folder written before it existed)
    pose_verdict: str = ""  # ok | doubtful | not assessed
    pose_reasons: str = ""  # the sequence's reasons, "; "-joined
    mapper: str = ""  # the mapper kept
    doubtful_frames: int | None = None  # registered frames called doubtful
    metrics: dict[str, float] = {}
    report: str | None = None  # report.html, relative to the workdir
    input: str = ""
    host: str = Field(default_factory=platform.node)


def failed_row(task: CaseTask, reason: str) -> CaseRow:
    return CaseRow(
        case=task.name, status="failed", reader=task.reader, reason=reason, input=task.input
    )


def numeric_leaves(data: Any, prefix: str = "") -> dict[str, float]:
    """Flatten a stage summary to its numbers: {"kept": 12, "dropped": {"blank": 1}} ->
    {"kept": 12.0, "dropped.blank": 1.0}. Booleans, strings and lists are left out."""
    out: dict[str, float] = {}
    if isinstance(data, dict):
        for k, v in data.items():
            out.update(numeric_leaves(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(data, (int, float)) and not isinstance(data, bool) and prefix:
        if math.isfinite(float(data)):
            out[prefix] = float(data)
    return out
