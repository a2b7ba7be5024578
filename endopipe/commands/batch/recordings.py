"""Recordings in a batch: a long input (a Hamlyn sequence, a whole video) goes through windows
as `endopipe run` sends it, its windows on the batch's executor, and gives one row of
batch.csv for the whole recording. Short inputs stay ordinary batch cases."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from rich.console import Console

from endopipe.commands.batch.rows import CaseRow, CaseTask, numeric_leaves
from endopipe.commands.recording.command import (
    RECORDING_DIR,
    RecordingOptions,
    is_recording,
    run_recording,
)
from endopipe.pipeline.errors import EndopipeError, one_line
from endopipe.pipeline.runner import Pipeline
from endopipe.pipeline.stage import StageConfig


def run_long_case(
    pipe: Pipeline,
    case_fn: Callable[[CaseTask], CaseRow],
    task: CaseTask,
    configs: dict[str, StageConfig],
    options: RecordingOptions,
    console: Console,
) -> CaseRow | None:
    """Ingest `task`'s input here; when its keyframes fill more than one window, run it as a
    recording (windows through `options.executor`) and return its row. None: it fits one
    window after all, and goes on as an ordinary batch case (its ingest is then cached)."""
    from endopipe.commands.cases import prepare_case

    t0 = time.perf_counter()
    row = CaseRow(case=task.name, status="failed", reader=task.reader, input=task.input)
    workdir = Path(task.workdir)
    try:
        case_dir = prepare_case(Path(task.input), workdir, task.name, None, task.reader)
        pipe.run(case_dir, configs, until="ingest", quiet=True, console=console)
        if not is_recording(pipe, case_dir, options):
            return None
        gt = pipe.view(case_dir, "ingest").ground_truth()
        row.gt_kind = gt.kind if gt is not None else ""
        summary = run_recording(
            pipe, case_fn, case_dir, configs, options, until=task.until, console=console
        )
    except EndopipeError as e:
        row.reason = one_line(e)
        row.wall_s = row.this_batch_s = time.perf_counter() - t0
        return row
    row.status = "ok"
    row.stages_ran = ["recording"]
    row.pose_verdict = summary.verdict
    row.pose_reasons = "; ".join(summary.reasons)
    row.compute_s = sum(w.wall_s for w in summary.windows)
    row.metrics = {
        f"recording.{k}": v
        for k, v in numeric_leaves(summary.model_dump(mode="json", exclude={"windows"})).items()
    }
    row.metrics["recording.windows"] = float(len(summary.windows))
    report = case_dir / RECORDING_DIR / "report.html"
    row.report = report.relative_to(workdir).as_posix() if report.is_file() else None
    row.wall_s = row.this_batch_s = time.perf_counter() - t0
    return row
