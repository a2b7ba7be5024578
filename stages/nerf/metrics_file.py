"""04_nerf/metrics.json (docs/formats.md), the held-out evaluation, as one model: the nerf stage
writes it through `NerfMetrics.write`, `NerfView.metrics` reads it back, and the report reads
its fields."""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict

from endopipe.pipeline.stage import write_json
from endopipe.stages.nerf.files import METRICS_FILE
from endopipe.stages.nerf.summary import NerfDepthScores


class NerfMetrics(BaseModel):
    """The frames held out of training, rendered after it: which, how fast, their PSNR and,
    with ground-truth depth, their depth scores. Keys another version wrote are kept."""

    model_config = ConfigDict(extra="allow", ser_json_inf_nan="constants")

    heldout: list[int] = []  # the frames evaluated
    render_rgb_ms: float | None = None  # median time to render one, colour and depth
    psnr: float | None = None  # mean over them, on their usable pixels
    depth: NerfDepthScores | None = None  # with ground-truth depth
    depth_frames: int | None = None  # ... on this many of them

    def write(self, folder: Path) -> None:
        """metrics.json in `folder`: the keys that were set, nothing added (NaN stays NaN, as
        the stage's other JSON writes it)."""
        write_json(Path(folder) / METRICS_FILE, self.model_dump(exclude_unset=True))

    @classmethod
    def read(cls, folder: Path) -> NerfMetrics | None:
        """The folder's metrics.json; None when absent (a ValueError when malformed)."""
        path = Path(folder) / METRICS_FILE
        return cls.model_validate_json(path.read_text()) if path.is_file() else None
