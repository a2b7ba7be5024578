"""`endopipe batch FOLDER`: find the cases, run them on an executor, write batch.csv/html."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from endopipe.commands.batch.added import per_case_added
from endopipe.commands.batch.page import write_html
from endopipe.commands.batch.table import write_csv
from endopipe.jobs.driver import run_cases
from endopipe.jobs.options import Execution
from endopipe.jobs.rows import CaseRow, CaseTask
from endopipe.pipeline.config import load_config
from endopipe.pipeline.errors import EndopipeError
from endopipe.pipeline.executors import ClusterConfig, load_cluster_config
from endopipe.pipeline.runner import Pipeline, ensure_writable
from endopipe.pipeline.stage import StageConfig

#: A case taken as a recording when it is one: its row, or None for an ordinary case.
LongCase = Callable[[CaseTask, dict[str, StageConfig]], CaseRow | None]


def run_batch(
    pipe: Pipeline,
    case_fn: Callable[[CaseTask], CaseRow],
    folder: Path,
    workdir: Path,
    *,
    config_files: Sequence[str] = (),
    sets: Sequence[str] = (),
    format_: str = "auto",
    execution: Execution,
    until: str | None = None,
    long_case: LongCase | None = None,
    dry_run: bool = False,
    right: Path | None = None,
    baseline_mm: float | None = None,
    depth_prior: Path | None = None,
    console: Console,
    out: Console,
) -> list[CaseRow]:
    """Every case under `folder` through `pipe` with `case_fn` (top-level, picklable: it runs
    in worker processes or cluster jobs). Raises when a case failed, after writing the table.

    `long_case` (the recording command, handed in by the composition root) takes a case first
    and returns its row when the case is a recording it ran (a long input whose keyframes fill
    more than one window: a Hamlyn sequence, a whole video), None when it is an ordinary case.
    Recordings go one after another, each using the executor for its windows; the ordinary
    cases go together. `right` / `depth_prior`: folders holding one folder per case
    (commands.batch.added); `baseline_mm` the rig's baseline, checked per case as `run` does."""
    from endopipe.stages.io.cases import find_cases

    if until is not None:
        pipe.index(until)
    configs = load_config(pipe.stages, config_files, sets)
    executor = execution.executor
    cluster = (
        load_cluster_config(execution.cluster_config) if executor != "local" else ClusterConfig()
    )
    ensure_writable(workdir)
    wd = workdir.resolve()
    beside = tuple(p.resolve() for p in (right, depth_prior) if p is not None)
    cases = find_cases(folder, format_, skip=(wd, *beside))
    if not cases:
        raise EndopipeError(
            f"no cases found in {folder}: expected videos, image folders, endopipe case folders "
            "or Hamlyn / C3VD / SimCol3D sequences (or pass --format)"
        )
    added = per_case_added(
        cases,
        folder,
        right=right,
        depth_prior=depth_prior,
        note=lambda m: console.print(f"[yellow]{escape(m)}[/yellow]"),
    )
    table = Table(title=f"{len(cases)} case(s) in {folder}")
    with_added = right is not None or depth_prior is not None
    for col in ("case", "reader", "input", "with")[: 3 + with_added]:
        table.add_column(col, overflow="fold")
    for c in cases:
        cells = [escape(c.name), c.format, escape(str(c.path))]
        if with_added:
            cells.append(added[c.name].said())
        table.add_row(*cells)
    out.print(table)
    if dry_run:
        return []
    resolved = {name: cfg.model_dump(mode="json") for name, cfg in configs.items()}
    tasks = [
        CaseTask(
            name=c.name,
            input=str(c.path.resolve()),
            reader=c.format,
            workdir=str(wd),
            configs=resolved,
            until=until,
            right=_text(added[c.name].right),
            # as `run` takes it (stages.io.added): with the case's right eye, or alone on its
            # own rig; a case --right gave no folder runs without a rig's baseline
            baseline_mm=baseline_mm if right is None or added[c.name].right else None,
            depth_prior=_text(added[c.name].depth_prior),
        )
        for c in cases
    ]
    t0 = time.perf_counter()
    recorded: dict[str, CaseRow] = {}
    for task in tasks if long_case is not None else []:
        row = long_case(task, configs)
        if row is not None:
            recorded[task.name] = row
            print_case_row(console, row)
    short = run_cases(
        executor,
        case_fn,
        [t for t in tasks if t.name not in recorded],
        jobs=execution.jobs,
        workdir=wd,
        cluster=cluster,
        ray_address=execution.ray_address,
        on_row=lambda row: print_case_row(console, row),
        note=lambda m: console.print(f"[dim]{escape(m)}[/dim]"),
    )
    by_name = recorded | {r.case: r for r in short}
    rows = [by_name[t.name] for t in tasks]
    elapsed = time.perf_counter() - t0
    csv_path = write_csv(rows, wd / "batch.csv")
    html_path = write_html(rows, wd / "batch.html", title=f"endopipe batch: {folder}")
    failed = [r for r in rows if r.status != "ok"]
    out.print(
        f"{len(rows)} case(s), {len(rows) - len(failed)} ok, {len(failed)} failed, "
        f"{elapsed:.1f} s with the {executor} executor -> {csv_path}, {html_path}"
    )
    if failed:
        raise EndopipeError(
            f"{len(failed)} of {len(rows)} case(s) failed; reasons in {csv_path}", exit_code=3
        )
    return rows


def _text(path: Path | None) -> str | None:
    return str(path.resolve()) if path is not None else None


def print_case_row(console: Console, row: CaseRow) -> None:
    """One line per finished case, as it finishes."""
    if row.status == "ok":
        ran = "+".join(row.stages_ran) or "nothing (all cached)"
        gt = f"  [yellow]{row.gt_kind} ground truth[/yellow]" if row.gt_kind == "pseudo" else ""
        if row.pose_verdict == "doubtful":
            gt += f"  [red]poses doubtful: {escape(row.pose_reasons)}[/red]"
        console.print(
            f"[green]✓[/green] {escape(row.case)}  [dim]{row.reader}[/dim]  ran {ran}, "
            f"{row.this_batch_s:.1f} s{gt}"
        )
    else:
        console.print(
            f"[red]✗[/red] {escape(row.case)}  [dim]{row.reader}[/dim]  {escape(row.reason)}"
        )
