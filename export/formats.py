"""A processed case written in another tool's format, one module per format.

Every format writes `export.json` (what was exported, units, conventions, the camera with its
lens, where the poses came from, skipped frames) next to its files. Only registered frames are
exported (in endopipe's frame order); the images are the working-resolution frames of 01_ingest,
the camera is scaled to them, and the poses are those the depth maps and the mesh were made at
(case.py). The folder is written beside `out` and renamed into place.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Mapping
from pathlib import Path

from endopipe.export.case import CaseExport, ExportResult, load_case_export
from endopipe.export.colmap import write_colmap
from endopipe.export.endonerf import ENDONERF_AXES, write_endonerf
from endopipe.export.nerfstudio import write_nerfstudio
from endopipe.export.pixels import RESOLUTIONS
from endopipe.export.ply import write_ply_export
from endopipe.export.targets import TARGETS, Target
from endopipe.pipeline.errors import EndopipeError
from endopipe.pipeline.stage import write_json

FORMATS = ("nerfstudio", "colmap", "endonerf", "ply")
#: The formats `--resolution source` writes (colmap's tracks and ply's points are the working
#: frames').
SOURCE_RESOLUTION_FORMATS = ("nerfstudio", "endonerf")
#: The loader `--format endonerf` is written for when neither --for nor --endonerf-axes is given.
DEFAULT_TARGET = "endonerf"


def export_case(
    case_dir: Path,
    fmt: str,
    out: Path | None = None,
    *,
    folders: Mapping[str, Path],
    symlink: bool = False,
    endonerf_axes: str | None = None,
    target: str | None = None,
    resolution: str = "working",
    point_stride: int = 4,
    max_points: int = 2_000_000,
) -> ExportResult:
    """Write `case_dir` in format `fmt` to `out` (default `<case>/exports/<fmt>`). `folders`:
    each stage's published folder by stage name (`Pipeline.folders`: the engine names them).
    endonerf: `target` (a loader of TARGETS; default endonerf) or `endonerf_axes` (the layout
    without a target: the camera as it is, translations in the case's units).

    An existing `out` is replaced only when it is an earlier endopipe export (it holds
    export.json), never a foreign folder.
    """
    if fmt not in FORMATS:
        raise EndopipeError(f"unknown export format '{fmt}'; formats: {', '.join(FORMATS)}")
    chosen = endonerf_choice(fmt, endonerf_axes, target)
    if resolution not in RESOLUTIONS:
        raise EndopipeError(f"unknown resolution '{resolution}'; choose {' or '.join(RESOLUTIONS)}")
    if resolution == "source" and fmt not in SOURCE_RESOLUTION_FORMATS:
        raise EndopipeError(
            f"--resolution source writes {' and '.join(SOURCE_RESOLUTION_FORMATS)}; {fmt} is "
            "written at the working resolution (its tracks / points are the working frames')"
        )
    case = load_case_export(case_dir, folders)
    out = Path(out) if out is not None else Path(case_dir) / "exports" / fmt
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not _ours(out))):
        raise EndopipeError(
            f"{out} exists and is not an endopipe export; give an empty or new folder with --out"
        )
    writers: dict[str, Callable[[Path], ExportResult]] = {
        "nerfstudio": lambda tmp: write_nerfstudio(
            case, tmp, symlink=symlink, resolution=resolution
        ),
        "colmap": lambda tmp: write_colmap(case, tmp, symlink=symlink),
        "endonerf": lambda tmp: write_endonerf(
            case,
            tmp,
            target=chosen if isinstance(chosen, Target) else None,
            axes=chosen if isinstance(chosen, str) else None,
            resolution=resolution,
        ),
        "ply": lambda tmp: write_ply_export(case, tmp, stride=point_stride, max_points=max_points),
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.parent / f".{out.name}.tmp-export"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        result = writers[fmt](tmp)
        if case.skipped:
            result.notes.append(f"{len(case.skipped)} unregistered frame(s) left out")
        extra: dict = {"resolution": resolution}
        if isinstance(chosen, Target):
            extra |= {"for": chosen.name, "endonerf_axes": chosen.axes}
        elif chosen is not None:
            extra |= {"endonerf_axes": chosen}
        write_json(tmp / "export.json", export_record(case, fmt, result) | extra)
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    result.out = out
    return result


def endonerf_choice(fmt: str, endonerf_axes: str | None, target: str | None) -> Target | str | None:
    """The EndoNeRF export's loader (a Target) or its explicit axes; None for other formats."""
    if target is not None and target not in TARGETS:
        raise EndopipeError(f"unknown --for '{target}'; choose one of {', '.join(TARGETS)}")
    if endonerf_axes is not None and endonerf_axes not in ENDONERF_AXES:
        raise EndopipeError(
            f"unknown EndoNeRF axes '{endonerf_axes}'; choose one of {', '.join(ENDONERF_AXES)}"
        )
    if fmt != "endonerf":
        if target is not None or endonerf_axes is not None:
            raise EndopipeError("--for and --endonerf-axes apply to --format endonerf only")
        return None
    if target is not None and endonerf_axes is not None:
        raise EndopipeError(
            f"--for {target} sets the axes ({TARGETS[target].axes}); drop --endonerf-axes"
        )
    if endonerf_axes is not None:
        return endonerf_axes
    return TARGETS[target or DEFAULT_TARGET]


def export_record(case: CaseExport, fmt: str, result: ExportResult) -> dict:
    """export.json: what was exported and in which conventions."""
    return {
        "format": fmt,
        "case": str(Path(case.case_dir).resolve()),
        "frames": [f.index for f in case.frames],
        "source_indices": [f.source_index for f in case.frames],
        "skipped_unregistered": case.skipped,
        "units": case.units,
        "metric": case.metric,
        "intrinsics": case.intrinsics.model_dump(exclude_none=True),
        "poses": case.poses_source,
        "poses_refined": case.refined,
        "notes": result.notes,
        "files": result.files,
    }


def _ours(folder: Path) -> bool:
    return (folder / "export.json").is_file()
