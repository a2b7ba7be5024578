"""Tool masks that come with an input, matched to its frames by the number in their names.

An instrument moves on its own and hides the tissue, so its pixels must leave the photometric
loss. Copies of a data set pad numbers differently (`000012.png`, `frame-12.mask.png`), so a
mask belongs to the frame whose file carries the same number, not to the same position.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from endopipe.pipeline.cache import digest_path, digest_text
from endopipe.stages.io.name_numbers import file_number

#: A case folder's tool masks (docs/formats.md), and EndoNeRF's.
TOOLS_DIR = "masks"
MASK_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}


@dataclass(frozen=True)
class ToolMasks:
    """Where the masks are and which file is which frame's (by source_index); a frame without
    a file has no tool in view."""

    folder: Path
    files: dict[int, Path] = field(default_factory=dict)
    #: How the data set's masks are drawn when it says so (StereoMIS: nonzero = tissue, so
    #: "black_is_tool"); None: as `ingest.tools.polarity` says.
    polarity: str | None = None

    def file(self, source_index: int) -> Path | None:
        return self.files.get(source_index)

    def digest(self) -> str:
        """The masks are part of the input: a changed mask must re-run ingest."""
        files = "|".join(f"{i}:{digest_path(p)}" for i, p in sorted(self.files.items()))
        return digest_text(files if self.polarity is None else f"{files}|{self.polarity}")


def numbered_masks(folder: Path) -> dict[int, Path]:
    """Mask files in `folder` by the number in their name (files without one left out)."""
    if not folder.is_dir():
        return {}
    out: dict[int, Path] = {}
    for p in sorted(folder.iterdir()):
        if p.is_file() and p.suffix.lower() in MASK_SUFFIXES and (n := file_number(p)) is not None:
            out.setdefault(n, p)
    return out


def masks_for_frames(folder: Path, frame_numbers: list[int | None] | None) -> ToolMasks | None:
    """The masks in `folder` for frames whose files carry `frame_numbers` (position =
    source_index; None: a video's frames, whose number is their position); None when the
    folder holds no numbered mask."""
    by_number = numbered_masks(folder)
    if not by_number:
        return None
    if frame_numbers is None:
        return ToolMasks(folder, by_number)
    files = {i: by_number[n] for i, n in enumerate(frame_numbers) if n in by_number}
    return ToolMasks(folder, files)
