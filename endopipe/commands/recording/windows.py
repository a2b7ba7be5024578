"""Cutting a recording's keyframes into overlapping windows.

Neighbouring windows share `overlap` keyframes: the join estimates the similarity between their
reconstructions from those shared cameras, so an overlap of fewer than 3 frames cannot join.
"""

from __future__ import annotations

from pydantic import BaseModel, Field

from endopipe.pipeline.errors import ConfigError


class WindowPlan(BaseModel):
    """How a recording was cut (recording/windows.json)."""

    size: int = Field(description="Keyframes per window.")
    overlap: int = Field(description="Keyframes shared by neighbouring windows.")
    windows: list[list[int]] = Field(description="Each window's keyframes, by source_index.")

    def name(self, k: int) -> str:
        return f"w{k:03d}"


def plan_windows(keyframes: list[int], size: int, overlap: int) -> WindowPlan:
    """Windows of `size` keyframes (source indices, ascending), each sharing `overlap` with the
    next; the last is shifted back to a full window rather than left short."""
    if overlap < 3 or overlap >= size:
        raise ConfigError(
            f"window overlap {overlap} must be at least 3 and under the window size {size} "
            "(neighbouring windows are joined on the cameras they share)"
        )
    n = len(keyframes)
    if n <= size:
        return WindowPlan(size=size, overlap=overlap, windows=[list(keyframes)])
    step = size - overlap
    starts = list(range(0, n - size + 1, step))
    if starts[-1] + size < n:  # the tail: one more full window ending at the last keyframe
        starts.append(n - size)
    return WindowPlan(
        size=size, overlap=overlap, windows=[list(keyframes[a : a + size]) for a in starts]
    )
