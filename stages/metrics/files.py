"""A stage's metrics.json as one pydantic model, written and read by the same class: the depth,
NeRF and mesh stages each declare their fields on it (docs/formats.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar, TypeVar

from pydantic import BaseModel

from endopipe.pipeline.stage import write_json

METRICS_FILE = "metrics.json"
M = TypeVar("M", bound="MetricsFile")


class MetricsFile(BaseModel):
    """metrics.json of a stage's folder: only the keys that were set are written, so the file
    says what was measured and nothing the model merely allows."""

    #: how the model is dumped: python values (NaN stays NaN, as the stages' JSON writes it)
    dump: ClassVar[dict[str, Any]] = {"exclude_unset": True}

    def write(self, folder: Path) -> None:
        write_json(Path(folder) / METRICS_FILE, self.model_dump(**self.dump))

    @classmethod
    def read(cls: type[M], folder: Path) -> M | None:
        """The folder's metrics.json; None when absent (a ValueError when malformed)."""
        path = Path(folder) / METRICS_FILE
        return cls.model_validate_json(path.read_text()) if path.is_file() else None
