"""How a command line ends: every failure the user can act on as one line on stderr and an
exit code, an endopipe bug as one line with its traceback in a log file, and Ctrl-C or SIGTERM
as a stop that says how to resume (finished stages are kept)."""

from __future__ import annotations

import shlex
import signal
import sys
import threading
import traceback
from pathlib import Path

import typer
from rich.markup import escape

from endopipe.commands.terminal import console
from endopipe.pipeline.errors import EndopipeError

#: The exit code of a run stopped by Ctrl-C (SIGINT), as shells report it (128 + 2).
INTERRUPTED = 130


def _click_errors() -> tuple[type[Exception], ...]:
    """Usage errors: those of the click that newer typer releases vendor, or click's own.
    (Imported here: click is not needed, nor loaded, unless a command line is wrong.)"""
    try:
        from typer._click.exceptions import ClickException
    except ImportError:  # typer < 0.20 uses click itself
        from click import ClickException
    return (ClickException,)


#: The exit code of a run stopped by SIGTERM (a scheduler's time limit or preemption, `kill`).
TERMINATED = 128 + signal.SIGTERM


class _Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the run is so that it unwinds as Ctrl-C does: the stage running
    keeps (resumable) or drops its temporary folder, and nothing is published half written."""


def interrupted(argv: list[str] | None, terminated: bool = False) -> int:
    """Ctrl-C or SIGTERM: say so, and how to go on; finished stages are kept and a re-run
    resumes."""
    command = shlex.join(["endopipe", *(sys.argv[1:] if argv is None else argv)])
    what = "terminated (SIGTERM)" if terminated else "interrupted"
    console.print(
        f"[bold red]{what}[/bold red]: finished stages are kept; "
        f"to resume, run the same command again: {escape(command)}",
        highlight=False,
        soft_wrap=True,
    )
    return TERMINATED if terminated else INTERRUPTED


def run_app(app: typer.Typer, argv: list[str] | None = None) -> int:
    """Run `app` on `argv`: one clear line and an exit code for every failure, never a traceback.

    With standalone_mode=False typer returns an exit code instead of exiting; Ctrl-C comes
    back as 130 (typer turns KeyboardInterrupt into Exit(130)), and must not end as 0. SIGTERM
    (what Slurm sends at a time limit, and `kill`) stops a run the same way, exit 143."""
    stops: list[BaseException] = []

    def on_sigterm(signum: int, frame: object) -> None:
        stops.append(_Terminated())
        raise stops[-1]

    if threading.current_thread() is not threading.main_thread():  # signals go to the main one
        return _main(app, argv, stops)
    previous = signal.signal(signal.SIGTERM, on_sigterm)
    try:
        return _main(app, argv, stops)
    finally:
        signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)


def _main(app: typer.Typer, argv: list[str] | None, stops: list) -> int:
    """run_app's body; `stops` holds the SIGTERM that stopped the run, if one did (typer turns
    it, as Ctrl-C, into an exit code of 130)."""
    try:
        code = app(args=argv, standalone_mode=False)
    except EndopipeError as e:
        console.print(
            f"[bold red]error:[/bold red] {escape(str(e))}", highlight=False, soft_wrap=True
        )
        return e.exit_code
    except typer.Exit as e:
        return e.exit_code
    except typer.Abort:
        if stops:
            return interrupted(argv, terminated=True)
        console.print("[bold red]aborted[/bold red]")
        return INTERRUPTED
    except _click_errors() as e:
        console.print(f"[bold red]error:[/bold red] {escape(e.format_message())}", soft_wrap=True)
        return e.exit_code
    except KeyboardInterrupt:
        return interrupted(argv, terminated=bool(stops))
    except Exception as e:  # an endopipe bug: one line here, the traceback in a log file
        log = Path.home() / ".cache" / "endopipe" / "last_error.log"
        try:
            log.parent.mkdir(parents=True, exist_ok=True)
            log.write_text(traceback.format_exc())
            where = f"; traceback in {log}"
        except OSError:
            where = ""
        console.print(
            f"[bold red]internal error:[/bold red] {type(e).__name__}: {escape(str(e))}{where}",
            highlight=False,
            soft_wrap=True,
        )
        return 1
    if code == INTERRUPTED:
        return interrupted(argv, terminated=bool(stops))
    return code if isinstance(code, int) else 0
