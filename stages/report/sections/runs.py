"""The case's recent runs (newest first: what ran, what came from the cache, how it ended) and
the environment of the newest."""

from __future__ import annotations

import os
import platform
from dataclasses import dataclass

import psutil

from endopipe.pipeline.runner import RunRecord
from endopipe.stages.report.kit import duration, render
from endopipe.stages.report.load import CaseData
from endopipe.stages.report.sections.common import ReportInfo


@dataclass(frozen=True)
class RunRow:
    """One run: started, result (a badge and why), wall time, what ran, what was cached."""

    started: str
    state: tuple[str, str]  # badge text, badge kind
    why: str
    wall: str
    ran: str
    cached: str


def run_state(record: RunRecord) -> tuple[str, str]:
    """The run's result as a badge. A record without an end is the run writing this page (its
    process is alive), or a run whose process died before it could record its end."""
    if record.finished is not None:
        return ("ok", "ok") if record.ok else ("failed", "bad")
    if record.pid == os.getpid() and record.host == platform.node():
        return ("this run, in progress", "warn")
    if record.host == platform.node() and record.pid and psutil.pid_exists(record.pid):
        return (f"in progress (pid {record.pid})", "warn")
    return ("no end recorded (killed?)", "bad")


def run_row(record: RunRecord) -> RunRow:
    failed = [s for s in record.stages if s.status == "failed"]
    why = failed[0].reason if failed else ""
    if record.finished is None:
        done = len(record.stages)
        why = f"{done} stage(s) done so far" if done else "no stage done yet"
    return RunRow(
        started=record.started,
        state=run_state(record),
        why=why,
        wall=duration(record.wall_s) + (" so far" if record.finished is None else ""),
        ran=", ".join(s.stage for s in record.stages if s.status == "ran") or "—",
        cached=", ".join(s.stage for s in record.stages if s.status == "cached") or "—",
    )


def section_runs(data: CaseData, info: ReportInfo) -> str | None:
    from endopipe.pipeline.runner import package_versions

    records = data.runs
    if records:
        packages = records[0].packages
        host, python = records[0].host, records[0].python
    else:
        packages, host, python = package_versions(), platform.node(), platform.python_version()
    return render(
        "sections/runs.html.j2",
        rows=[run_row(r) for r in records],
        in_progress=bool(records) and records[0].finished is None,
        host=host,
        python=python,
        packages=", ".join(f"{k} {v}" for k, v in sorted(packages.items())),
    )
