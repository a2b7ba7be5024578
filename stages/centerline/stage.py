"""centerline: the lumen's centre curve and radius from the camera path and the sparse points.

Seed §3.3's tube prior (the steps are in tube.py's docstring), or an ellipsoid for a cavity.

`prior: cavity` fits an ellipsoid to the points instead (robust algebraic fit, refined by
robust least squares on the point-to-ellipsoid distance).

The estimation is plain functions over arrays, testable without the pipeline: `fit_tube`
(tube.py), `fit_cavity` (cavity.py), `compare_to_truth` (evaluate.py); plot.py draws
centerline.png and view.py is the only reader of the stage's folder.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from endopipe.pipeline.errors import StageFailed
from endopipe.pipeline.stage import Stage, StageContext, Summary, write_json
from endopipe.stages.centerline.cavity import fit_cavity
from endopipe.stages.centerline.config import CenterlineConfig
from endopipe.stages.centerline.evaluate import compare_to_truth
from endopipe.stages.centerline.plot import plot_centerline
from endopipe.stages.centerline.tube import fit_tube
from endopipe.stages.centerline.view import (
    CENTERLINE_FILE,
    PLOT_FILE,
    PRIOR_FILE,
    CenterlineView,
)
from endopipe.stages.poses.view import PosesView

__all__ = ["Centerline", "CenterlineConfig", "CenterlineSummary", "CenterlineView"]


class CenterlineSummary(Summary):
    kind: str
    length: float
    mean_radius: float
    radius_source: str
    radius_note: str
    n_points_used: int
    n_cameras: int
    units: str
    recentred_slices: int = 0
    centerline_mean_dist: float | None = None
    centerline_mean_dist_pct_of_radius: float | None = None
    radius_error_pct: float | None = None


class Centerline(Stage):
    """Centre curve and radius of the lumen (or an ellipsoid cavity) as the NeRF's prior."""

    name = "centerline"
    needs = ("poses",)
    version = 2
    Config = CenterlineConfig

    @classmethod
    def view(cls, folder: Path) -> CenterlineView:
        return CenterlineView(folder)

    def run(self, ctx: StageContext) -> CenterlineSummary:
        cfg: CenterlineConfig = ctx.config  # type: ignore[assignment]
        poses: PosesView = ctx.input("poses")
        centres = poses.centres()
        if len(centres) == 0:
            raise StageFailed("centerline: no registered cameras in 02_poses")
        view_dirs = np.array([poses.c2w[i][:3, 2] for i in poses.registered]).reshape(-1, 3)
        points = poses.points()
        units = poses.file.units
        fitter = fit_cavity if cfg.prior == "cavity" else fit_tube
        fit = fitter(centres, view_dirs, points, cfg, metric=poses.metric)
        for note in fit.notes:
            ctx.log(note)
        prior = fit.prior(cfg.far_radii)
        prior.save(ctx.out / PRIOR_FILE)
        write_json(
            ctx.out / CENTERLINE_FILE,
            fit.to_file(units).model_dump(mode="json", exclude_none=True),
        )

        truth = None
        scores: dict[str, float] = {}
        if ctx.case.gt_dir and poses.metric:
            from endopipe.stages.io.ground_truth import GroundTruth

            gt_dir = Path(ctx.case.gt_dir)
            truth = (
                GroundTruth(gt_dir).centerline() if (gt_dir / "centerline.json").is_file() else None
            )
            if truth is not None and fit.kind == "tube":
                scores = compare_to_truth(fit, *truth)
        plot_centerline(ctx.out / PLOT_FILE, fit, centres, points, units, truth)
        summary = CenterlineSummary(
            kind=fit.kind,
            length=fit.length,
            mean_radius=prior.typical_radius
            if fit.kind == "cavity"
            else float(np.mean(fit.radius)),
            radius_source=fit.radius_source,
            radius_note=fit.radius_note,
            n_points_used=fit.n_points_used,
            n_cameras=len(centres),
            units=units,
            recentred_slices=fit.recentred_slices,
            **{k: v for k, v in scores.items() if k.startswith(("centerline_", "radius_"))},
        )
        ctx.log(
            f"{fit.kind}: length {fit.length:.1f} {units}, mean radius "
            f"{summary.mean_radius:.2f} {units} ({fit.radius_note})"
            + (
                f"; vs truth: {scores['centerline_mean_dist_pct_of_radius']:.1f}% of radius, "
                f"radius error {scores['radius_error_pct']:.1f}%"
                if scores
                else ""
            )
        )
        return summary
