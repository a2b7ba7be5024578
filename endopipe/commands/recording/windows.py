"""Cutting a recording's keyframes into overlapping windows.

Neighbouring windows share `overlap` keyframes: the join estimates the similarity between their
reconstructions from those shared cameras, so an overlap of fewer than 3 frames cannot join.
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, Field

from endopipe.pipeline.errors import ConfigError


class WindowPlan(BaseModel):
    """How a recording was cut (recording/windows.json)."""

    size: int = Field(description="Keyframes per window, at most.")
    overlap: int = Field(description="Keyframes shared by neighbouring windows.")
    windows: list[list[int]] = Field(description="Each window's keyframes, by source_index.")

    def name(self, k: int) -> str:
        return f"w{k:03d}"


def plan_windows(keyframes: list[int], size: int, overlap: int) -> WindowPlan:
    """As few windows of at most `size` keyframes (source indices, ascending) as cover them
    with `overlap` shared between neighbours, all of one length and evenly spread (no short
    tail window, no window that repeats most of its neighbour)."""
    if overlap < 3 or overlap >= size:
        raise ConfigError(
            f"window overlap {overlap} must be at least 3 and under the window size {size} "
            "(neighbouring windows are joined on the cameras they share)"
        )
    n = len(keyframes)
    if n <= size:
        return WindowPlan(size=size, overlap=overlap, windows=[list(keyframes)])
    count = math.ceil((n - overlap) / (size - overlap))
    length = math.ceil((n + (count - 1) * overlap) / count)
    starts = np.linspace(0, n - length, count).round().astype(int)
    return WindowPlan(
        size=size,
        overlap=overlap,
        windows=[list(keyframes[a : a + length]) for a in starts],
    )
