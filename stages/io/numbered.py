"""Which file of a folder belongs to which frame: by the number in its name, as the tool masks
and the data sets' depth files are matched (a video's frame number is its position).

Why one helper: `--right` and `--depth-prior` folders come from other tools that name files
their own way (`0000000012.jpg`, `frame_12_depth.npy`); the number is what they share."""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path

from endopipe.pipeline.errors import InputError
from endopipe.stages.io.name_numbers import file_number


def numbered_files(folder: Path, suffixes: Collection[str], what: str) -> dict[int, Path]:
    """The files of `folder` with one of `suffixes`, by the number in their name; a folder that
    is not there, or two files with one number, is refused in one line."""
    if not folder.is_dir():
        raise InputError(f"{what} {folder} is not a folder")
    out: dict[int, Path] = {}
    for p in sorted(folder.iterdir()):
        if not (p.is_file() and p.suffix.lower() in suffixes):
            continue
        n = file_number(p)
        if n is None:
            continue
        if n in out:
            raise InputError(
                f"{what} {folder}: {out[n].name} and {p.name} both carry the number {n}; keep "
                "one file per frame"
            )
        out[n] = p
    return out


def by_source_index(
    files: dict[int, Path], numbers: list[int] | None, count: int | None
) -> dict[int, Path]:
    """`files` (by number) re-keyed by the frame's source_index: the frame whose file carries
    that number, or (a video: `numbers` None) the frame at that position (within `count`
    frames when known)."""
    if numbers is None:
        return {n: p for n, p in files.items() if count is None or 0 <= n < count}
    return {i: files[n] for i, n in enumerate(numbers) if n in files}
