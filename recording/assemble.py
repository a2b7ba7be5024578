"""A recording put together once its windows have run: the windows joined into one trajectory,
its scale redrawn for the drift the light measures, every frame posed and given depth, the
keyframes fused into one mesh, a page, all published as `<case>/recording/`.

A re-run whose windows are all fresh and whose recording/ was published with the same key
reads it back instead (the engine's freshness check: key and files).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from rich.console import Console

from endopipe.jobs.rows import CaseRow
from endopipe.pipeline.runner import PeakMemory, Pipeline
from endopipe.pipeline.stage import CaseInfo, StageConfig
from endopipe.recording.cameras import truth_poses, window_poses
from endopipe.recording.frames import pose_every_frame
from endopipe.recording.fuse import one_mesh
from endopipe.recording.join import Joined, join_windows
from endopipe.recording.light_scale import correct_drift
from endopipe.recording.options import RecordingOptions
from endopipe.recording.paths import REPORT_FILE
from endopipe.recording.report import write_report
from endopipe.recording.store import RecordingInputs, Staging
from endopipe.recording.summary import LightScale, RecordingSummary
from endopipe.recording.verdict import joined_ate, summarise
from endopipe.recording.view import RecordingView
from endopipe.recording.windows import WindowPlan


@dataclass
class Assembled:
    """The recording as published (or found fresh: `cached`)."""

    summary: RecordingSummary
    joined: Joined
    cached: bool


def assemble(
    pipe: Pipeline,
    case_dir: Path,
    plan: WindowPlan,
    rows: list[CaseRow],
    configs: dict[str, StageConfig],
    options: RecordingOptions,
    *,
    until: str | None,
    one_sfm: bool,
    console: Console,
) -> Assembled:
    """Join the windows that ran (`rows`, in `plan` order) and publish recording/."""
    view = RecordingView(case_dir)
    inputs = RecordingInputs(pipe, case_dir, plan, configs, options, until)
    if all(r.status == "ok" and not r.stages_ran for r in rows) and view.is_fresh(inputs.key):
        return Assembled(view.summary, view.trajectory(), cached=True)
    ingest = pipe.view(case_dir, "ingest")
    poses = [
        window_poses(pipe, view.windows_dir / row.case) if row.status == "ok" else None
        for row in rows
    ]
    joined = join_windows(plan.names(), poses, plan.windows, plan.breaks)
    truth = truth_poses(ingest)
    as_joined = joined
    joined, light = _redraw_for_light(pipe, view, joined, configs, ingest, options, until)
    summary = summarise(plan, rows, joined, truth)
    summary.one_sfm = one_sfm
    summary.light_scale = light
    if light.applied:
        summary.ate_as_joined_pct = joined_ate(as_joined, truth)[0]
    with PeakMemory() as memory:
        staging = Staging(case_dir, inputs)
        frames = None
        if _reaches(pipe, until, "depth"):
            info = CaseInfo.load(case_dir)
            frames = pose_every_frame(
                pipe, info, view.windows_dir, joined, configs, ingest, staging.dir, summary, console
            )
        if _reaches(pipe, until, "mesh"):
            mesh = one_mesh(pipe, view.windows_dir, joined, configs, ingest, truth, summary)
            if mesh is not None:
                from endopipe.stages.mesh.view import save_mesh

                save_mesh(staging.dir, mesh)
        write_report(
            staging.dir / REPORT_FILE,
            case_dir.name,
            summary,
            plan,
            joined,
            [f.source_index for f in ingest.frames],
            ingest.file.dropped_frames,
            frames,
            truth,
            _window_pages(pipe, view, plan),
        )
        staging.publish(plan, joined, summary, memory.peak_mb)
    return Assembled(summary, joined, cached=False)


def _reaches(pipe: Pipeline, until: str | None, stage: str) -> bool:
    return until is None or pipe.index(until) >= pipe.index(stage)


def _redraw_for_light(
    pipe: Pipeline,
    view: RecordingView,
    joined: Joined,
    configs: dict[str, StageConfig],
    ingest,
    options: RecordingOptions,
    until: str | None,
) -> tuple[Joined, LightScale]:
    """The joined path redrawn for the scale drift the light measures, when asked and the
    windows have depth maps to measure it with."""
    if not options.light_scale:
        return joined, LightScale(applied=False, reason="not asked (--no-light-scale)")
    if not _reaches(pipe, until, "depth"):
        return joined, LightScale(applied=False, reason="no depth maps yet to measure it with")
    return correct_drift(pipe, view.windows_dir, joined, ingest, configs["mesh"].min_opacity)


def _window_pages(pipe: Pipeline, view: RecordingView, plan: WindowPlan) -> dict[str, str]:
    """Each window's own report, as a link relative to recording/ (those that have one)."""
    if "report" not in pipe.by_name:
        return {}
    pages = {}
    for name in plan.names():
        page = pipe.view(view.windows_dir / name, "report").page
        if page.is_file():
            pages[name] = Path(os.path.relpath(page, view.folder)).as_posix()
    return pages
