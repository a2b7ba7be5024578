"""Whether an input is a recording, and how its keyframes are cut into overlapping windows,
each a case of the same stages with its own settings.

Neighbouring windows share `overlap` keyframes: the join estimates the similarity between their
reconstructions from those shared cameras (`RecordingOptions` keeps the overlap at 3 or more and
under the window's length). Where the recording's one SfM hangs together by few points (a weak
link, `stages/poses/links.py`), the keyframes either side are cut into windows of their own: no
window straddles the link, and the join starts a new segment there.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, Field

from endopipe.pipeline.errors import InputError
from endopipe.pipeline.runner import Pipeline
from endopipe.pipeline.stage import StageConfig
from endopipe.recording.one_sfm import window_settings
from endopipe.recording.options import RecordingOptions


class WindowPlan(BaseModel):
    """How a recording was cut (recording/windows.json)."""

    size: int = Field(description="Keyframes per window, at most.")
    overlap: int = Field(description="Keyframes shared by neighbouring windows.")
    windows: list[list[int]] = Field(description="Each window's keyframes, by source_index.")
    breaks: dict[int, str] = Field(
        default_factory=dict,
        description="Windows that start a new stretch (by position), and why: the keyframes "
        "before them are not placed against theirs.",
    )

    def name(self, k: int) -> str:
        """Window k's case name under `<case>/windows/`."""
        return f"w{k:03d}"

    def names(self) -> list[str]:
        return [self.name(k) for k in range(len(self.windows))]


def plan_windows(
    keyframes: list[int], options: RecordingOptions, cuts: dict[int, str] | None = None
) -> WindowPlan:
    """As few windows of at most `options.window` keyframes (source indices, ascending) as cover
    them with `options.overlap` shared between neighbours, all of one length and evenly spread
    (no short tail window, no window that repeats most of its neighbour). `cuts`: keyframes
    that start a new stretch (and why); each stretch is cut on its own."""
    from endopipe.stages.poses.links import split_at

    cuts = cuts or {}
    windows: list[list[int]] = []
    breaks: dict[int, str] = {}
    for stretch in split_at(keyframes, cuts):
        if windows:
            breaks[len(windows)] = cuts[stretch[0]]
        windows += _cut(stretch, options.window, options.overlap)
    return WindowPlan(size=options.window, overlap=options.overlap, windows=windows, breaks=breaks)


def _cut(keyframes: list[int], size: int, overlap: int) -> list[list[int]]:
    n = len(keyframes)
    if n <= size:
        return [list(keyframes)]
    count = math.ceil((n - overlap) / (size - overlap))
    length = math.ceil((n + (count - 1) * overlap) / count)
    starts = np.linspace(0, n - length, count).round().astype(int)
    return [list(keyframes[a : a + length]) for a in starts]


def is_long_input(
    path: Path, intrinsics: Path | None, fmt: str | None, configs: dict[str, StageConfig]
) -> bool:
    """Whether ingest will keep this input's frames by content (a long input): only then is
    its ingest run first, to see whether the keyframes fill more than one window. An input
    that cannot be opened is not (its own run says what is wrong, or goes on from its cache)."""
    from endopipe.stages.ingest.keyframes import keyframes_on
    from endopipe.stages.io.sources import open_input

    try:
        source = open_input(path, intrinsics, format=fmt)
    except InputError:
        return False
    return keyframes_on(configs["ingest"].keyframes, source.frame_count())


def is_recording(pipe: Pipeline, case_dir: Path, options: RecordingOptions) -> bool:
    """Whether ingest kept this input's frames by content and kept more than one window."""
    ingest = pipe.view(case_dir, "ingest")
    return bool(ingest.summary.keyframes) and len(ingest.frames) > options.window


def window_configs(
    configs: dict[str, StageConfig], frames: list[int], shared: Path | None = None
) -> dict[str, dict[str, Any]]:
    """The run's settings for one window: ingest takes exactly its keyframes (already vetted
    for blur, light and motion by the recording's own ingest); with `shared`, the poses and
    lumen of the recording's one SfM."""
    resolved = {name: cfg.model_dump(mode="json") for name, cfg in configs.items()}
    if shared is not None:
        for stage, settings in window_settings(shared).items():
            resolved[stage] = {**resolved[stage], **settings}
    ingest = copy.deepcopy(resolved["ingest"])
    ingest.update(
        frames=frames,
        stride=1,
        max_frames=None,
        start_s=0.0,
        end_s=None,
        drop_duplicates=False,
        drop_blurred=False,
    )
    ingest["keyframes"]["mode"] = "all"
    resolved["ingest"] = ingest
    return resolved
