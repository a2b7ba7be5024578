"""Ground truth kept as one depth file per input frame: what the data set readers share.

A reader's class says where each frame's depth file is and how its values become depth
(`decode_depth`); this base answers the ground-truth protocol (ground_truth.GroundTruthSource)
by source_index, so reading, indexing and counting are written once. Readers with poses
override `has_poses` and `poses`.
"""

from __future__ import annotations

import re
from abc import ABC, abstractmethod
from pathlib import Path
from typing import ClassVar

import cv2
import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.stages.io.ground_truth import GtKind


def numbered(folder: Path, pattern: re.Pattern[str]) -> list[tuple[int, Path]]:
    """(number, file) for files whose name matches `pattern` (group 1 is the number), sorted by
    number: zero padding differs between copies of a data set."""
    if not folder.is_dir():
        return []
    out = [(int(m.group(1)), p) for p in folder.iterdir() if (m := pattern.match(p.name))]
    return sorted(out)


class PerFrameGroundTruth(ABC):
    """Depth files by source_index (None where a frame has none), decoded by the subclass."""

    dataset: ClassVar[str]
    kind: ClassVar[GtKind]
    units: ClassVar[str] = "mm"
    #: The data set's name in messages.
    title: ClassVar[str]
    #: How cv2 reads a depth file; a colour file gives its first channel.
    read_flag: ClassVar[int] = cv2.IMREAD_UNCHANGED

    def __init__(self, folder: Path, depth_files: list[Path | None], depth_count: int) -> None:
        self.dir = Path(folder)
        self._files = depth_files
        self._count = depth_count

    @abstractmethod
    def decode_depth(self, raw: np.ndarray) -> np.ndarray:
        """A depth file's values as float32 depth in `units` (0 = invalid)."""

    def depth_file(self, source_index: int) -> Path | None:
        if not 0 <= source_index < len(self._files):
            return None
        return self._files[source_index]

    def depth(self, source_index: int) -> np.ndarray | None:
        path = self.depth_file(source_index)
        if path is None:
            return None
        raw = cv2.imread(str(path), self.read_flag)
        if raw is None:
            raise InputError(f"cannot read {self.title} depth {path}")
        return self.decode_depth(raw[..., 0] if raw.ndim == 3 else raw)

    def has_depth(self, source_index: int) -> bool:
        return self.depth_file(source_index) is not None

    def depth_count(self) -> int:
        return self._count

    def has_poses(self) -> bool:
        return False

    def poses(self) -> list[np.ndarray]:
        return []


class NumberedGroundTruth(PerFrameGroundTruth):
    """Frames and depth files named by number (`frame_pattern`, `depth_pattern`): a frame's
    source_index is its position in numeric order, its depth the file with its number."""

    frame_pattern: ClassVar[re.Pattern[str]]
    depth_pattern: ClassVar[re.Pattern[str]]
    #: Where the frames and the depth files are, in the sequence folder.
    frame_folder: ClassVar[str] = "."
    depth_folder: ClassVar[str] = "."

    def __init__(self, seq: Path) -> None:
        seq = Path(seq)
        frames = numbered(seq / self.frame_folder, self.frame_pattern)
        depth = dict(numbered(seq / self.depth_folder, self.depth_pattern))
        self.numbers = [n for n, _ in frames]
        self.frames = [f for _, f in frames]
        super().__init__(seq, [depth.get(n) for n in self.numbers], len(depth))
