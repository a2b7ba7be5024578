"""Sends jobs (cases) to one of the engine's executors and gathers one row per job."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import as_completed
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from endopipe.jobs.rows import CaseRow, CaseTask, failed_row
from endopipe.pipeline.errors import one_line
from endopipe.pipeline.executors import ClusterConfig, local_executor, make_executor, thread_env


def run_cases(
    kind: str,
    fn: Callable[[CaseTask], CaseRow],
    tasks: Sequence[CaseTask],
    *,
    jobs: int | None,
    workdir: Path,
    cluster: ClusterConfig,
    ray_address: str | None = None,
    on_row: Callable[[CaseRow], None] = lambda row: None,
    note: Callable[[str], None] = print,
) -> list[CaseRow]:
    """Run `fn` on every task with executor `kind`; one row per task, in task order.

    Each case is first checked here (`check_only`): only those with work left are sent to the
    executor, which is not even started when there are none.

    A case whose job dies (a crash, a Slurm job killed, a Ray task lost) gets a failed row
    with the reason; the others carry on. With the local executor a crashed worker process
    breaks the whole pool, so the cases it took down are re-run one at a time, each in a
    fresh process, to tell the culprit from the bystanders.
    """
    rows: dict[str, CaseRow] = {}
    todo = list(tasks)
    if todo:
        # No job (nor worker process, nor cluster) for a case with nothing left to do, or
        # whose input cannot be used: a finished batch re-runs in seconds.
        for task in list(todo):
            row = fn(task.model_copy(update={"check_only": True}))
            if row.status != "pending":
                rows[task.name] = row
                todo.remove(task)
                on_row(row)
    if not todo:
        return [rows[t.name] for t in tasks]
    executor, threads = make_executor(
        kind,
        jobs=jobs,
        workdir=workdir,
        cluster=cluster,
        ray_address=ray_address,
        note=note,
        tasks=len(todo),
    )
    todo = [t.model_copy(update={"threads": threads}) for t in todo]
    crashed: list[CaseTask] = []
    with thread_env(threads):
        try:
            if hasattr(executor, "submit_many"):
                futures = executor.submit_many(fn, [(t,) for t in todo])
            else:
                futures = [executor.submit(fn, t) for t in todo]
            by_future = dict(zip(futures, todo, strict=True))
            for future in as_completed(by_future):
                task = by_future[future]
                try:
                    row = future.result()
                except BrokenProcessPool:
                    crashed.append(task)
                    continue
                except Exception as e:
                    row = failed_row(task, f"{kind} job failed: {one_line(e)}")
                rows[task.name] = row
                on_row(row)
        except BaseException:
            executor.shutdown(wait=False, cancel_futures=True)
            raise
        executor.shutdown(wait=True)
        for task in crashed:  # local only: isolate the case that killed its worker
            with local_executor(1, threads) as alone:
                try:
                    row = alone.submit(fn, task).result()
                except BrokenProcessPool:
                    row = failed_row(task, "its worker process died (a crash, or out of memory)")
            rows[task.name] = row
            on_row(row)
    return [rows[t.name] for t in tasks]
