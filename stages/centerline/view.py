"""`03_centerline` (centerline.json, prior.npz): the file models and the only reader of the
folder. Downstream stages take the lumen prior from `CenterlineView.prior()`."""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

import numpy as np
from pydantic import BaseModel

from endopipe.pipeline.errors import EndopipeError
from endopipe.pipeline.stage import read_summary
from endopipe.stages.centerline.prior import LumenPrior, load_prior
from endopipe.stages.centerline.summary import CenterlineSummary

CENTERLINE_FILE = "centerline.json"
PRIOR_FILE = "prior.npz"
PLOT_FILE = "centerline.png"


class EllipsoidFile(BaseModel):
    centre: list[float]
    axes: list[float]
    rotation: list[list[float]]  # columns: the axes' directions


class CenterlineFile(BaseModel):
    """centerline.json: curve samples (uniform in arc length) with a radius each, in `units`."""

    kind: str  # "tube" | "cavity"
    units: str = ""
    points: list[list[float]]
    radius: list[float]
    arclength: list[float]
    camera_span: tuple[float, float] | None = None  # arc length range the cameras project to
    radius_source: str | None = None  # "points" | "fallback"
    ellipsoid: EllipsoidFile | None = None  # cavity only


class CenterlineView:
    """Typed access to 03_centerline: the curve, and the prior for torch."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.file = CenterlineFile.model_validate_json((self.folder / CENTERLINE_FILE).read_text())
        self.kind: str = self.file.kind
        self.units: str = self.file.units
        self.points = np.asarray(self.file.points, np.float64)
        self.radius = np.asarray(self.file.radius, np.float64)
        self.arclength = np.asarray(self.file.arclength, np.float64)

    @cached_property
    def summary(self) -> CenterlineSummary:
        """The stage's summary in its manifest, as the model the stage wrote (SummaryMismatch
        when the folder was written with other fields)."""
        return read_summary(self.folder, CenterlineSummary)

    @property
    def prior_path(self) -> Path:
        return self.folder / PRIOR_FILE

    @property
    def plot_path(self) -> Path:
        return self.folder / PLOT_FILE

    def prior(self) -> LumenPrior:
        """The lumen prior (TubePrior or EllipsoidPrior) the NeRF, depth and mesh stages use."""
        if not self.prior_path.is_file():
            raise EndopipeError(f"no lumen prior at {self.prior_path}; re-run the centerline stage")
        return load_prior(self.prior_path)
