"""The cameras a recording works with, keyed by source frame (the key a recording's windows,
and a windowed and a single run of one input, share), and the truth's cameras the same way."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.pipeline.runner import Pipeline


def cameras_by_source(pipe: Pipeline, case_dir: Path) -> dict[int, np.ndarray]:
    """A case's registered cameras (c2w) keyed by source frame."""
    ingest = pipe.view(case_dir, "ingest")
    poses = pipe.view(case_dir, "poses")
    return {ingest.frame(i).source_index: c2w for i, c2w in poses.c2w.items()}


def window_poses(pipe: Pipeline, window_dir: Path) -> dict[int, np.ndarray] | None:
    """A window's registered cameras by source frame (None: no poses to join)."""
    try:
        return cameras_by_source(pipe, window_dir)
    except (OSError, ValueError):
        return None


def truth_poses(ingest: Any) -> list[np.ndarray] | None:
    """The true c2w of every input frame, by source_index, through the frame -> truth mapping
    (None: no truth, or unreadable: the recording is then not scored)."""
    from endopipe.stages.io.ground_truth import poses_by_frame

    try:
        gt = ingest.ground_truth()
        count = len(gt.poses()) if gt is not None and gt.has_poses() else 0
        every = [_Frame(i, i) for i in range(count)]
        truth = poses_by_frame(gt, every) if count else None
    except InputError:
        return None
    return [truth[i] for i in range(count)] if truth else None


@dataclass(frozen=True)
class _Frame:
    """An input frame as the frame -> truth mapping reads it (index = source_index here)."""

    index: int
    source_index: int
