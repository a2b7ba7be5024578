"""`endopipe export CASE --format F`: a processed case in another tool's format (the export
library, `endopipe.export`), and what was written, in a few lines."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from endopipe.commands.cases import resolve_case
from endopipe.commands.terminal import out

if TYPE_CHECKING:
    from endopipe.pipeline.runner import Pipeline


def export_command(
    pipe: Pipeline,
    case: str,
    workdir: Path,
    fmt: str,
    out_dir: Path | None,
    *,
    symlink: bool,
    endonerf_axes: str | None = None,
    target: str | None = None,
    resolution: str = "working",
) -> None:
    """Export CASE (a folder, or a name under the workdir); the stage folders are the engine's."""
    from endopipe.export import export_case

    case_dir = resolve_case(case, workdir)
    result = export_case(
        case_dir,
        fmt,
        out_dir,
        folders=pipe.folders(case_dir),
        symlink=symlink,
        endonerf_axes=endonerf_axes,
        target=target,
        resolution=resolution,
    )
    out.print(f"exported {result.frames} frame(s) as {result.format} to {result.out}")
    for note in result.notes:
        out.print(f"  {note}", markup=False, highlight=False)
