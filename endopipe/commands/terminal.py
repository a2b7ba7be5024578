"""The two consoles every command writes to: progress and errors on stderr, results on stdout,
so a command's output can be piped or redirected without its progress bars."""

from __future__ import annotations

from rich.console import Console

console = Console(stderr=True)
out = Console()
