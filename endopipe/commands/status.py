"""`endopipe status`: each stage of a case as fresh, stale (and why), missing or running, from
the folders alone (no stage is imported, so it answers in a fraction of a second)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from rich.markup import escape
from rich.table import Table

from endopipe.commands.cases import resolve_case
from endopipe.commands.terminal import out

if TYPE_CHECKING:
    from endopipe.pipeline.runner import Pipeline

COLOURS = {"fresh": "green", "stale": "yellow", "missing": "red", "running": "cyan"}


def show_status(
    pipe: Pipeline, case: str, workdir: Path, config_files: list[str], sets: list[str]
) -> None:
    """The table of CASE's stages, judged against its last run's configuration, or against
    the given --config/--set (would that config re-run?)."""
    from endopipe.pipeline.config import load_config

    case_dir = resolve_case(case, workdir)
    given = bool(config_files or sets)
    configs = load_config(pipe.stages, config_files, sets) if given else None
    plan = pipe.status(case_dir, configs)
    running = pipe.in_progress(case_dir)
    against = "the given --config/--set" if given else "the configuration of its last run"
    table = Table(title=f"{case_dir.name}", caption=f"judged against {against}")
    for col in ("stage", "state", "why", "folder"):
        table.add_column(col)
    for p in plan:
        state = "fresh" if p.fresh else ("missing" if p.reason == "missing" else "stale")
        why = p.reason
        if running is not None and running.running == p.stage:
            since = running.started.split("T")[-1]
            state, why = "running", f"pid {running.pid} on {running.host}, run started {since}"
        colour = COLOURS[state]
        table.add_row(p.stage, f"[{colour}]{state}[/{colour}]", escape(why), p.folder)
    out.print(table)
    if running is not None:
        out.print(
            f"a run is in progress (pid {running.pid} on {running.host}): {running.running} is "
            "running; stages after it are judged by what is on disk now",
            highlight=False,
        )
    show_windows(case_dir)


def show_windows(case_dir: Path) -> None:
    """A recording's windows, each a case of its own: where they are and how the last join
    went, read through the recording's view (the stages above are the whole recording's: its
    ingest, and its poses and centerline when it was posed by one SfM)."""
    from endopipe.pipeline.errors import SummaryMismatch
    from endopipe.recording.view import RecordingView

    view = RecordingView(case_dir)
    windows = view.window_dirs()
    if not windows:
        return
    line = f"a recording in {len(windows)} windows, each a case: endopipe status {windows[0]}"
    if view.exists():
        try:
            s = view.summary
            ok = sum(w.status == "ok" for w in s.windows)
            line += f"; last join: {ok} of {len(s.windows)} windows ok, verdict {s.verdict}"
        except SummaryMismatch as e:
            line += f"; {e}"
    else:
        line += "; not joined yet"
    out.print(escape(line), highlight=False, soft_wrap=True)
