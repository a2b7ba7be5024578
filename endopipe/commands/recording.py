"""A recording through windows: its keyframes (the whole input's ingest) cut into overlapping
windows, each window a case of the same stages under `<case>/windows/`, sent as jobs to an
executor as batch sends its cases, then put together as `<case>/recording/` (the recording
library, `endopipe.recording`).

A window that fails or is doubtful is reported and the others carry on; a re-run does only the
windows with work left (each window is a cached case).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from endopipe.commands.cases import prepare_case
from endopipe.jobs.case import task_added
from endopipe.jobs.driver import run_cases
from endopipe.jobs.options import Execution
from endopipe.jobs.rows import CaseRow, CaseTask, numeric_leaves
from endopipe.pipeline.errors import EndopipeError, one_line
from endopipe.pipeline.executors import ClusterConfig, load_cluster_config
from endopipe.pipeline.runner import Pipeline
from endopipe.pipeline.stage import CaseInfo, StageConfig
from endopipe.recording.assemble import assemble
from endopipe.recording.join import Joined
from endopipe.recording.one_sfm import pose_once, stretch_cuts
from endopipe.recording.options import RecordingOptions
from endopipe.recording.summary import RecordingSummary, light_line
from endopipe.recording.view import RecordingView
from endopipe.recording.windows import (
    is_long_input,
    is_recording,
    plan_windows,
    window_configs,
)

#: A job: one case (a window, or the recording's own case for its one SfM) -> its row.
CaseFn = Callable[[CaseTask], CaseRow]


def run_recording(
    pipe: Pipeline,
    case_fn: CaseFn,
    case_dir: Path,
    configs: dict[str, StageConfig],
    options: RecordingOptions,
    execution: Execution,
    *,
    until: str | None,
    console: Console,
    from_stage: str | None = None,
    force: bool = False,
) -> RecordingSummary:
    """Cut, run every window, put together; writes <case>/recording/ and prints a table."""
    info = CaseInfo.load(case_dir)
    ingest = pipe.view(case_dir, "ingest")
    keyframes = [f.source_index for f in ingest.frames]
    view = RecordingView(case_dir)
    windows_dir = view.windows_dir.resolve()
    windows_dir.mkdir(exist_ok=True)
    send = _sender(case_fn, execution, windows_dir, console)
    shared = None
    cuts: dict[int, str] = {}
    if len(keyframes) <= options.one_sfm_up_to and (
        until is None or pipe.index(until) >= pipe.index("poses")
    ):
        whole = CaseTask(
            name=case_dir.name,
            input=info.input,
            reader=info.kind,
            workdir=str(case_dir.parent.resolve()),
            configs={name: cfg.model_dump(mode="json") for name, cfg in configs.items()},
            until="centerline",
            intrinsics=info.intrinsics_file,
            right=info.right,
            baseline_mm=info.baseline_mm,
            depth_prior=info.depth_prior,
            from_stage=from_stage if from_stage in ("ingest", "poses", "centerline") else None,
            force=force,
        )
        shared = pose_once(pipe, case_dir, send([whole], lambda row: None)[0], console)
        if shared is not None:
            cuts = stretch_cuts(pipe, case_dir)
    plan = plan_windows(keyframes, options, cuts)
    console.print(
        f"[bold]{escape(info.name)}[/bold]: a recording of {len(keyframes)} keyframes in "
        f"{len(plan.windows)} windows of up to {max(map(len, plan.windows))} "
        f"({plan.overlap} or more shared), {execution.executor} executor"
    )
    for k, why in plan.breaks.items():
        console.print(f"[yellow]{plan.name(k)} starts a new stretch: {escape(why)}[/yellow]")
    tasks = [
        CaseTask(
            name=plan.name(k),
            input=info.input,
            reader=info.kind,
            workdir=str(windows_dir),
            configs=window_configs(configs, frames, shared),
            until=until,
            intrinsics=info.intrinsics_file,
            right=info.right,
            baseline_mm=info.baseline_mm,
            depth_prior=info.depth_prior,
            from_stage=from_stage,
            force=force,
        )
        for k, frames in enumerate(plan.windows)
    ]
    rows = send(tasks, lambda row: _print_window(console, row))
    made = assemble(
        pipe,
        case_dir,
        plan,
        rows,
        configs,
        options,
        until=until,
        one_sfm=shared is not None,
        console=console,
    )
    if made.cached:
        console.print("[dim]recording cached: every window fresh, joined before[/dim]")
    _print_summary(console, made.summary, made.joined, view.folder)
    return made.summary


def recording_row(
    pipe: Pipeline,
    case_fn: CaseFn,
    options: RecordingOptions,
    execution: Execution,
    console: Console,
    task: CaseTask,
    configs: dict[str, StageConfig],
) -> CaseRow | None:
    """A batch's case run as a recording when it is one: a long input is ingested here and,
    when its keyframes fill more than one window, run through windows on the batch's executor;
    one row for the whole recording. None: an ordinary case (its ingest, if run, is cached)."""
    if not is_long_input(Path(task.input), None, task.reader, configs):
        return None
    t0 = time.perf_counter()
    row = CaseRow(case=task.name, status="failed", reader=task.reader, input=task.input)
    workdir = Path(task.workdir)
    try:
        added = task_added(task)
        case_dir = prepare_case(Path(task.input), workdir, task.name, None, task.reader, added)
        pipe.run(case_dir, configs, until="ingest", quiet=True, console=console)
        if not is_recording(pipe, case_dir, options):
            return None
        gt = pipe.view(case_dir, "ingest").ground_truth()
        row.gt_kind = gt.kind if gt is not None else ""
        summary = run_recording(
            pipe, case_fn, case_dir, configs, options, execution, until=task.until, console=console
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
    report = RecordingView(case_dir).report_page
    row.report = report.relative_to(workdir).as_posix() if report.is_file() else None
    row.wall_s = row.this_batch_s = time.perf_counter() - t0
    return row


def _sender(
    case_fn: CaseFn, execution: Execution, workdir: Path, console: Console
) -> Callable[[list[CaseTask], Callable[[CaseRow], None]], list[CaseRow]]:
    """Sends tasks through the job driver on the run's executor."""
    cluster = (
        load_cluster_config(execution.cluster_config)
        if execution.executor != "local"
        else ClusterConfig()
    )

    def send(tasks: list[CaseTask], on_row: Callable[[CaseRow], None]) -> list[CaseRow]:
        return run_cases(
            execution.executor,
            case_fn,
            tasks,
            jobs=execution.jobs,
            workdir=workdir,
            cluster=cluster,
            ray_address=execution.ray_address,
            on_row=on_row,
            note=lambda m: console.print(f"[dim]{escape(m)}[/dim]"),
        )

    return send


def _print_window(console: Console, row: CaseRow) -> None:
    if row.status == "ok":
        verdict = " [red]poses doubtful[/red]" if row.pose_verdict == "doubtful" else ""
        ran = f"ran {'+'.join(row.stages_ran)}" if row.stages_ran else "all cached"
        console.print(f"[green]✓[/green] {row.case}  {ran}, {row.this_batch_s:.1f} s{verdict}")
    else:
        console.print(f"[red]✗[/red] {row.case}  {escape(row.reason)}")


def _print_summary(
    console: Console, summary: RecordingSummary, joined: Joined, folder: Path
) -> None:
    table = Table(title="windows")
    for col in ("window", "frames", "status", "poses", "junction", "depth AbsRel"):
        table.add_column(col)
    error = {j.b: j for j in joined.junctions}
    for w in summary.windows:
        j = error.get(w.name)
        junction = "" if j is None else (f"{j.error_pct:.2f}%" if j.error_pct is not None else "-")
        if j is not None and not j.joined:
            junction = f"[red]{escape(j.reason)}[/red]"
        absrel = f"{w.depth_abs_rel:.4f}" if w.depth_abs_rel is not None else ""
        table.add_row(w.name, str(w.frames), w.status, w.pose_verdict, junction, absrel)
    console.print(table)
    ate = (
        f"; ATE {summary.ate_percent_of_path:.2f}% of the path over {summary.ate_frames} keyframes"
        if summary.ate_percent_of_path is not None
        else ""
    )
    if len(summary.ate_by_segment) > 1:
        ate += (
            " (each segment on its own: "
            + ", ".join(
                f"{a.percent_of_path:.2f}% over {a.keyframes}" for a in summary.ate_by_segment
            )
            + ")"
        )
    if summary.depth_abs_rel_all_frames is not None:
        relative = summary.depth_gt_kind == "relative"
        spearman = f"Spearman {summary.depth_spearman_all_frames:.3f}, " if relative else ""
        one_scale = (
            f"; one scale a segment {summary.depth_abs_rel_one_scale:.4f}"
            if summary.depth_abs_rel_one_scale is not None
            else ""
        )
        ate += (
            f"; {summary.frames_posed} of {summary.frames} frames posed, depth {spearman}"
            f"{'SSI-' if relative else ''}AbsRel {summary.depth_abs_rel_all_frames:.4f}, "
            f"coverage {summary.depth_coverage_all_frames:.3f} over "
            f"{summary.depth_frames_scored} frames (keyframes alone "
            f"{summary.depth_abs_rel_keyframes:.4f}{one_scale}; a guess from shading alone "
            f"{summary.brightness_guess_abs_rel:.3f})"
        )
    if summary.chamfer_pct_radius is not None:
        ate += (
            f"; one mesh of {summary.mesh_frames} keyframes: Chamfer "
            f"{summary.chamfer_pct_radius:.2f}% of the radius, {summary.off_seen_pct:.1f}% off "
            "the seen surface"
        )
    colour = "green" if summary.verdict == "ok" else "yellow"
    how = " by one SfM" if summary.one_sfm else ""
    console.print(
        f"[{colour}]{summary.verdict}[/{colour}]: {summary.posed_keyframes} of "
        f"{summary.keyframes} keyframes posed{how} in {summary.segments} segment(s){ate} -> "
        f"{folder}",
        soft_wrap=True,
    )
    for reason in summary.reasons:
        console.print(f"  [yellow]{escape(reason)}[/yellow]", soft_wrap=True)
    if summary.light_scale is not None:
        console.print(f"  [dim]{escape(light_line(summary))}[/dim]", soft_wrap=True)
    if summary.windows and all(w.status != "ok" for w in summary.windows):
        raise EndopipeError("every window of the recording failed; see the table above")
