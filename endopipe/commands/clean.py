"""`endopipe clean`: remove a case's stage outputs, all of them or one stage and what depends
on it (what depends on a removed stage would be stale anyway)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from endopipe.commands.cases import resolve_case
from endopipe.commands.terminal import out

if TYPE_CHECKING:
    from pathlib import Path

    from endopipe.pipeline.runner import Pipeline


def clean_case(pipe: Pipeline, case: str, workdir: Path, stage: str | None) -> None:
    """Remove the folders and say which."""
    case_dir = resolve_case(case, workdir)
    if stage is not None:
        pipe.index(stage)
    removed = pipe.clean(case_dir, stage)
    out.print(f"removed {len(removed)} folder(s): {', '.join(removed) or 'none'}")
