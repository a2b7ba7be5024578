"""User-facing errors: one line naming the problem and what to do, never a traceback."""

from __future__ import annotations


class EndopipeError(Exception):
    """An error the user can act on. `str(err)` is the one line the CLI prints."""

    exit_code = 2

    def __init__(self, message: str, exit_code: int | None = None) -> None:
        super().__init__(message)
        if exit_code is not None:
            self.exit_code = exit_code


class InputError(EndopipeError):
    """The input (video, folder, intrinsics file) cannot be used."""


class ConfigError(EndopipeError):
    """A config file or --set value is wrong."""


class StageFailed(EndopipeError):
    """A stage ran but its result did not pass a quality gate."""

    exit_code = 3


class SummaryMismatch(EndopipeError):
    """A stage folder's manifest summary is not the model its stage reads today (written by
    another version of endopipe, or edited by hand)."""


class CaseLocked(EndopipeError):
    """Another endopipe process is working on the same case."""

    exit_code = 4


def one_line(e: BaseException | str, limit: int = 300) -> str:
    """The first non-empty line of an error, cut to `limit` characters: what a table cell or
    a log line can hold."""
    text = str(e).strip()
    line = next((ln.strip() for ln in text.splitlines() if ln.strip()), type(e).__name__)
    return line if len(line) <= limit else line[: limit - 1] + "…"
