"""Where the cases of a batch folder are, and which reader `open_input` would pick for each.

A folder that a reader accepts is one case (an endopipe case folder, a data set sequence); a
video file is one; a folder of loose images is one only when nothing below it is.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from endopipe.pipeline.errors import InputError
from endopipe.stages.io.case_folder import case_folder_of
from endopipe.stages.io.datasets import READERS, detect_dataset
from endopipe.stages.io.images import IMAGE_SUFFIXES
from endopipe.stages.io.sources import FORMATS
from endopipe.stages.io.video import VIDEO_SUFFIXES

MAX_DEPTH = 8


#: Folders of depth maps (Hamlyn's depth01/, EDaM's and EndoNeRF's depth/): 16-bit PNGs that
#: look like images but are never frames to reconstruct.
DEPTH_FOLDER = re.compile(r"^depth\d*$", re.IGNORECASE)


def _has_images(folder: Path) -> bool:
    if DEPTH_FOLDER.match(folder.name):
        return False
    return any(p.suffix.lower() in IMAGE_SUFFIXES and p.is_file() for p in folder.iterdir())


def detect_format(path: Path) -> str | None:
    """The reader `open_input` would pick for `path`, or None when nothing reads it."""
    path = Path(path)
    if path.is_file():
        if path.suffix.lower() in VIDEO_SUFFIXES:
            return "case" if case_folder_of(path) is not None else "video"
        return None
    if not path.is_dir():
        return None
    if case_folder_of(path) is not None:
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
        return path.is_dir() and case_folder_of(path) is not None
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
