"""Which reader reads a path, and where the cases of a data set folder are.

Readers: an endopipe case folder ("case"), a video file ("video"), a folder of images
("images"), and the data sets read in place, one module each: Hamlyn ("hamlyn", rectified
release), C3VD ("c3vd"), SimCol3D ("simcol3d") and C3VD v3's preview frames ("c3vd_preview").
Detection looks at the files, never at folder names, so a renamed copy is still recognised;
`--format` overrides it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io import c3vd, c3vd_preview, hamlyn, simcol3d
from endopipe.stages.io.sources import (
    FORMATS,
    IMAGE_SUFFIXES,
    VIDEO_SUFFIXES,
    InputSource,
    _case_folder_of,
)

#: Data set readers, in detection order. Each module has NAME, LAYOUT, GT_KIND,
#: is_sequence(path), open_sequence(path, intrinsics) and ground_truth(gt_dir).
READERS: dict[str, ModuleType] = {m.NAME: m for m in (hamlyn, c3vd, simcol3d, c3vd_preview)}

DESCRIPTIONS = {
    "case": "endopipe case folder (intrinsics.json + video.mp4 or frames/, optional gt/)",
    "video": "video file",
    "images": "folder of images",
    **{name: f"{name}: {m.LAYOUT}" for name, m in READERS.items()},
}
MAX_DEPTH = 8


def detect_dataset(path: Path) -> str | None:
    """The data set reader for a sequence folder, or None."""
    path = Path(path)
    if not path.is_dir():
        return None
    for name, reader in READERS.items():
        if reader.is_sequence(path):
            return name
    return None


def open_dataset(path: Path, fmt: str, intrinsics: Camera | None = None) -> InputSource:
    reader = READERS.get(fmt)
    if reader is None:
        raise InputError(f"unknown data set format '{fmt}'; formats: {', '.join(READERS)}")
    if not reader.is_sequence(Path(path)):
        raise InputError(f"{path} is not a {fmt} sequence ({reader.LAYOUT})")
    return reader.open_sequence(Path(path).resolve(), intrinsics)  # gt_dir lands in case.json


def _has_images(folder: Path) -> bool:
    return any(p.suffix.lower() in IMAGE_SUFFIXES and p.is_file() for p in folder.iterdir())


def detect_format(path: Path) -> str | None:
    """The reader `open_input` would pick for `path`, or None when nothing reads it."""
    path = Path(path)
    if path.is_file():
        if path.suffix.lower() in VIDEO_SUFFIXES:
            return "case" if _case_folder_of(path) is not None else "video"
        return None
    if not path.is_dir():
        return None
    if _case_folder_of(path) is not None:
        return "case"
    return detect_dataset(path) or ("images" if _has_images(path) else None)


def accepts(path: Path, fmt: str) -> bool:
    """Whether reader `fmt` can read `path` (used when --format overrides detection)."""
    path = Path(path)
    if fmt == "auto":
        return detect_format(path) is not None
    if fmt == "video":
        return path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES
    if fmt == "images":
        return path.is_dir() and _has_images(path)
    if fmt == "case":
        return path.is_dir() and _case_folder_of(path) is not None
    return path.is_dir() and READERS[fmt].is_sequence(path)


@dataclass(frozen=True)
class FoundCase:
    name: str  # unique case name: the path under the batch folder, "/" -> "__"
    path: Path
    format: str  # the reader picked (or forced)


def find_cases(root: Path, fmt: str = "auto", skip: tuple[Path, ...] = ()) -> list[FoundCase]:
    """Every case under `root` (or `root` itself when it is one), in sorted order.

    A folder that a reader accepts is one case and is not searched further; otherwise its
    video files are cases and its sub-folders are searched. A folder of loose images counts
    only when nothing below it is a case. Hidden folders, `skip` (the workdir) and endopipe
    output folders (holding case.json) are ignored.
    """
    if fmt not in FORMATS:
        raise InputError(f"unknown format '{fmt}'; formats: {', '.join(FORMATS)}")
    root = Path(root).expanduser()
    if not root.exists():
        raise InputError(f"batch folder not found: {root}")
    skipped = {Path(p).resolve() for p in skip}
    seen: set[Path] = set()
    found: list[tuple[Path, str]] = []

    def reader_for(path: Path) -> str | None:
        if fmt == "auto":
            return detect_format(path)
        return fmt if accepts(path, fmt) else None

    def visit(folder: Path, depth: int) -> None:
        real = folder.resolve()
        if real in seen or real in skipped or (folder / "case.json").is_file():
            return
        seen.add(real)
        kind = reader_for(folder)
        if kind is not None and kind != "images":
            found.append((folder, kind))
            return
        before = len(found)
        try:
            entries = sorted(folder.iterdir(), key=_natural)
        except OSError:
            return
        for p in entries:
            if p.name.startswith(".") or not p.is_file():
                continue
            if p.suffix.lower() in VIDEO_SUFFIXES and fmt in ("auto", "video"):
                found.append((p, "video"))
        if depth < MAX_DEPTH:
            for p in entries:
                if p.is_dir() and not p.name.startswith((".", "__")):
                    visit(p, depth + 1)
        if kind == "images" and len(found) == before:
            found.append((folder, "images"))

    if root.is_file():
        kind = reader_for(root)
        if kind is None:
            raise InputError(f"{root} is not a video, an image folder or a data set folder")
        found.append((root, kind))
    else:
        visit(root, 0)
    found.sort(key=lambda item: _natural(item[0]))
    return _name_cases(root, found)


def _natural(path: Path) -> tuple:
    return tuple(int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", str(path)))


def _name_cases(root: Path, found: list[tuple[Path, str]]) -> list[FoundCase]:
    out, used = [], set()
    for path, kind in found:
        rel = path.relative_to(root) if path != root else Path(root.name)
        parts = list(rel.parts) or [root.name]
        if path.is_file() and kind == "case":  # <case>/video.mp4 -> <case>
            parts = parts[:-1] or [path.parent.name]
        elif path.is_file():
            parts[-1] = path.stem
        name = re.sub(r"[^A-Za-z0-9._-]+", "_", "__".join(parts)).strip("_") or "case"
        unique, n = name, 2
        while unique in used:
            unique, n = f"{name}-{n}", n + 1
        used.add(unique)
        out.append(FoundCase(unique, path, kind))
    return out
