"""Tool masks given with the input: a case folder's `masks/` (docs/formats.md), EndoNeRF's
convention: 255 where an instrument is, 0 on tissue, named by the frame's position in the input.

Why read them: an instrument moves on its own and hides the tissue; its pixels must leave the
photometric loss, and the depth under it is inferred, never observed. A mask that marks most of
a frame as tool is almost surely the other polarity (255 = keep): refused with one line rather
than training on the instrument alone.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.stages.io.case_folder import case_folder_of

TOOLS_DIR = "masks"
#: Past this share of a frame marked as tool, a mask is taken for the other polarity.
MOST_OF_THE_FRAME = 0.6


def tool_masks_of(input_path: Path) -> Path | None:
    """The case folder's `masks/` when the input is a case folder that has one."""
    case = case_folder_of(Path(input_path))
    folder = case / TOOLS_DIR if case is not None else None
    return folder if folder is not None and folder.is_dir() else None


def read_tool_mask(folder: Path, source_index: int, size: tuple[int, int]) -> np.ndarray | None:
    """(H, W) bool at the working `size` (w, h): True on the tool; None when the frame has no
    mask file (no tool in it)."""
    path = folder / f"{source_index:06d}.png"
    if not path.is_file():
        return None
    grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if grey is None:
        raise InputError(f"{path} is not a readable image; remove it or replace it")
    tool = cv2.resize(grey, size, interpolation=cv2.INTER_NEAREST) > 127
    if tool.mean() > MOST_OF_THE_FRAME:
        raise InputError(
            f"{path} marks {tool.mean():.0%} of the frame as tool: endopipe reads 255 = tool, "
            "0 = tissue (EndoNeRF's convention); invert the masks if yours mark what to keep"
        )
    return tool
