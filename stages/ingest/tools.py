"""Tool masks given with the input (a case folder's or EndoNeRF's `masks/`), read at the
working size in the polarity `ingest.tools.polarity` says.

Why read them: an instrument moves on its own and hides the tissue; its pixels must leave the
photometric loss, and the depth under it is inferred, never observed. With polarity auto a mask
reads 255 = tool (EndoNeRF's convention), and one that marks most of its frame as tool is almost
surely the other polarity (255 = keep): refused with one line rather than training on the
instrument alone.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from endopipe.pipeline.errors import InputError

#: Past this share of a frame marked as tool, a mask read with polarity auto is refused.
MOST_OF_THE_FRAME = 0.6
FLIP = "--set ingest.tools.polarity=black_is_tool"


def polarity_said(polarity: str) -> str:
    """The polarity in the words of the log and the summary."""
    return "0 = tool" if polarity == "black_is_tool" else "255 = tool"


def read_tool_mask(path: Path, size: tuple[int, int], polarity: str = "auto") -> np.ndarray:
    """(H, W) bool at the working `size` (w, h): True on the tool. A 0/1 mask reads as a
    0/255 one."""
    grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if grey is None:
        raise InputError(f"{path} is not a readable image; remove it or replace it")
    white = grey > (127 if grey.max() > 1 else 0)
    white = cv2.resize(white.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    tool = ~white if polarity == "black_is_tool" else white
    if polarity == "auto" and tool.mean() > MOST_OF_THE_FRAME:
        raise InputError(
            f"{path} marks {tool.mean():.0%} of the frame as tool: endopipe reads 255 = tool, "
            f"0 = tissue (EndoNeRF's convention); if yours mark what to keep, add {FLIP}"
        )
    return tool
