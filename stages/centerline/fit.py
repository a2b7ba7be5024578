"""What a lumen fit returns (`CenterlineFit`), and the robust helpers the tube and cavity fits
share.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from endopipe.stages.centerline.config import CenterlineConfig
from endopipe.stages.centerline.prior import EllipsoidPrior, LumenPrior, TubePrior
from endopipe.stages.centerline.view import CenterlineFile, EllipsoidFile

MAD_TO_SIGMA = 1.4826


@dataclass
class CenterlineFit:
    """A fitted lumen: curve samples (uniform in arc length) with a radius each."""

    kind: str
    points: np.ndarray  # (M, 3)
    radius: np.ndarray  # (M,)
    arclength: np.ndarray  # (M,)
    radius_source: str  # "points" | "fallback"
    radius_note: str
    n_points_used: int
    camera_span: tuple[float, float]  # arc length range the cameras project to
    recentred_slices: int = 0
    bins: tuple[np.ndarray, np.ndarray] = field(
        default_factory=lambda: (np.zeros(0), np.zeros(0))
    )  # raw per-slice radius (arc length, radius), for plots
    ellipsoid: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # centre, axes, rotation
    notes: list[str] = field(default_factory=list)

    @property
    def length(self) -> float:
        return float(self.arclength[-1]) if len(self.arclength) else 0.0

    def prior(self, far_radii: float = 6.0) -> LumenPrior:
        if self.ellipsoid is not None:
            return EllipsoidPrior(*self.ellipsoid, far_radii=far_radii)
        return TubePrior(self.points, self.radius, open_ends=True, far_radii=far_radii)

    def to_file(self, units: str) -> CenterlineFile:
        """centerline.json's content (rounded to 6 decimals: the file diffs cleanly)."""
        ellipsoid = None
        if self.ellipsoid is not None:
            c, a, r = self.ellipsoid
            ellipsoid = EllipsoidFile(centre=c.tolist(), axes=a.tolist(), rotation=r.tolist())
        return CenterlineFile(
            kind=self.kind,
            units=units,
            points=np.round(self.points, 6).tolist(),
            radius=np.round(self.radius, 6).tolist(),
            arclength=np.round(self.arclength, 6).tolist(),
            camera_span=(round(self.camera_span[0], 6), round(self.camera_span[1], 6)),
            radius_source=self.radius_source,
            ellipsoid=ellipsoid,
        )


def robust_inliers(values: np.ndarray, k: float) -> np.ndarray:
    """Mask of values within k MADs (as sigma) of the median."""
    if len(values) == 0:
        return np.zeros(0, dtype=bool)
    med = np.median(values)
    mad = MAD_TO_SIGMA * np.median(np.abs(values - med))
    if mad <= 1e-12 * max(abs(med), 1.0):
        return np.ones(len(values), dtype=bool)
    return np.abs(values - med) <= k * mad


def default_radius(centres: np.ndarray, metric: bool, cfg: CenterlineConfig) -> float:
    """The radius when no point is usable: a typical colon's in mm, else a fraction of the
    camera path."""
    if metric:
        return cfg.default_radius_mm
    length = float(np.linalg.norm(np.diff(centres, axis=0), axis=1).sum()) if len(centres) else 0
    return cfg.default_radius_fraction * length if length > 0 else 1.0


def subsample(points: np.ndarray, n: int) -> np.ndarray:
    """At most n of the points, picked with a fixed seed (the fit is reproducible)."""
    if len(points) <= n:
        return points
    idx = np.random.default_rng(0).choice(len(points), n, replace=False)
    return points[np.sort(idx)]
