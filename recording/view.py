"""`<case>/recording/` and `<case>/windows/`: the only reader of what a recording writes, beside
the code that writes it (`store.py`); the names are those of `paths.py`.

`recording/` is published like a stage's folder (`manifest.json` last, with its cache key and
summary, then renamed into place); its files are listed in docs/formats.md.
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

from endopipe.pipeline.cache import Manifest, freshness
from endopipe.pipeline.stage import read_summary
from endopipe.recording.paths import (
    DEPTH_DIR,
    FRAMES_FILE,
    MESH_FILE,
    RECORDING_DIR,
    REPORT_FILE,
    TRAJECTORY_FILE,
    WINDOWS_DIR,
    WINDOWS_FILE,
)
from endopipe.recording.summary import RecordingSummary

# The trajectory, the cut and the frames come with numpy and OpenCV: imported when read, so
# `endopipe status` reads the summary in a fraction of a second.
if TYPE_CHECKING:
    from endopipe.recording.frames import FramePose
    from endopipe.recording.join import Joined
    from endopipe.recording.windows import WindowPlan


class RecordingView:
    """A case's recording: its windows (each a case folder) and its joined outputs."""

    def __init__(self, case_dir: Path) -> None:
        self.case_dir = Path(case_dir)
        self.folder = self.case_dir / RECORDING_DIR
        self.windows_dir = self.case_dir / WINDOWS_DIR
        self.depth_dir = self.folder / DEPTH_DIR  # every posed frame's depth, by source_index
        self.report_page = self.folder / REPORT_FILE
        self.mesh_file = self.folder / MESH_FILE

    def window_dirs(self) -> list[Path]:
        """The windows run so far, each a case folder, in order."""
        if not self.windows_dir.is_dir():
            return []
        return sorted(p for p in self.windows_dir.iterdir() if (p / "case.json").is_file())

    def exists(self) -> bool:
        """Whether a recording was joined and published here."""
        return Manifest.load(self.folder) is not None

    def is_fresh(self, key: str) -> bool:
        """Published with this key, every file intact."""
        return freshness(self.folder, key)[0]

    @cached_property
    def summary(self) -> RecordingSummary:
        return read_summary(self.folder, RecordingSummary)

    def trajectory(self) -> Joined:
        from endopipe.recording.join import Joined

        return Joined.model_validate_json((self.folder / TRAJECTORY_FILE).read_text())

    def plan(self) -> WindowPlan:
        from endopipe.recording.windows import WindowPlan

        return WindowPlan.model_validate_json((self.folder / WINDOWS_FILE).read_text())

    def frames(self) -> list[FramePose]:
        """Every frame from the first keyframe to the last (empty when not made: --until)."""
        from endopipe.recording.frames import FramesFile

        path = self.folder / FRAMES_FILE
        if not path.is_file():
            return []
        return FramesFile.model_validate_json(path.read_text()).frames
