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
from endopipe.pipeline.stage import Stage, StageContext, write_json
from endopipe.stages.centerline.cavity import fit_cavity
from endopipe.stages.centerline.choose import (
    choose_prior,
    empty_core,
    point_reach,
    reaching_margin,
)
from endopipe.stages.centerline.config import CenterlineConfig
from endopipe.stages.centerline.evaluate import compare_to_truth
from endopipe.stages.centerline.given import place_given_prior
from endopipe.stages.centerline.plot import plot_centerline
from endopipe.stages.centerline.prior import FreePrior, LumenPrior, save_prior
from endopipe.stages.centerline.summary import CenterlineSummary
from endopipe.stages.centerline.tube import fit_tube
from endopipe.stages.centerline.view import (
    CENTERLINE_FILE,
    PLOT_FILE,
    PRIOR_FILE,
    CenterlineFile,
    CenterlineView,
)
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.poses.view import PosesView

__all__ = ["Centerline", "CenterlineConfig", "CenterlineSummary", "CenterlineView"]


class Centerline(Stage):
    """Centre curve and radius of the lumen (or an ellipsoid cavity) as the NeRF's prior."""

    name = "centerline"
    needs = ("ingest", "poses")
    # 9: a stereo pair alone as a still one; 8: a still stereo camera's scene unit is its
    # measured depth (mm)
    version = 9
    Config = CenterlineConfig
    Summary = CenterlineSummary
    View = CenterlineView

    def run(self, ctx: StageContext[CenterlineConfig]) -> CenterlineSummary:
        cfg = ctx.config
        poses = ctx.input(PosesView)
        centres = poses.centres()
        if len(centres) == 0:
            raise StageFailed("centerline: no registered cameras in 02_poses")
        if poses.still or poses.one_pair:
            ingest = ctx.input(IngestView)
            typical = stereo_typical_depth(ingest, poses)
            why = "one stereo pair is one view" if poses.one_pair else "the camera stands still"
            return no_parallax(ctx, centres, typical, ingest.stereo_measured_by, why)
        view_dirs = np.array([poses.c2w[i][:3, 2] for i in poses.registered]).reshape(-1, 3)
        points = poses.points()
        units = poses.file.units
        fits = {
            "tube": fit_tube(centres, view_dirs, points, cfg, metric=poses.metric),
            "cavity": fit_cavity(centres, view_dirs, points, cfg, metric=poses.metric),
        }
        frames, origins, seen = observation_rays(ctx.input(IngestView), poses, points)
        candidates = {k: f.prior(cfg.far_radii) for k, f in fits.items()}
        choice = choose_prior(
            candidates,
            origins,
            seen,
            cfg.fit_tolerance,
            cfg.min_fit,
            forced=None if cfg.prior == "auto" else cfg.prior,
            insist=cfg.insist,
        )
        ctx.log(f"prior: {choice.kind} ({choice.reason})")
        # The file and plot show the best-fitting shape even when no prior is used.
        best = max(choice.scores, key=lambda sc: sc.inlier_fraction).kind
        fit = fits[choice.kind if choice.kind in fits else best]
        for note in fit.notes:
            ctx.log(note)
        c2w = {i: poses.c2w[i] for i in poses.registered}
        seen_reach = point_reach(c2w, frames, seen)
        reach = cfg.reach_margin * seen_reach if seen_reach > 0 else None
        prior: LumenPrior
        if choice.kind == "none":
            dist = np.linalg.norm(seen - origins, axis=1) if len(seen) else np.ones(1)
            depth = float(np.median(dist))
            scale = cfg.free_scale * depth
            prior = FreePrior(centres.mean(0), scale, reach or 12.0 * scale, depth)
        else:
            prior = candidates[choice.kind]
            prior.weight = choice.weight
            prior.reach = reach
            if choice.scale_from is not None:
                prior.unit = candidates[choice.scale_from].typical_radius
            prior.margin = reaching_margin(prior, origins, seen, cfg.reach_share)
            ctx.log(
                f"{choice.kind}: {100 * cfg.reach_share:.0f}% of the SfM points lie within "
                f"{1 + prior.margin:.2f}x its wall (rays are sampled at least that far)"
            )
            prior.core_limit = empty_core(prior, seen, cfg.core_share)
            if prior.core_limit < 1.0:
                ctx.log(
                    f"{choice.kind}: its empty core (L_prior) is at most "
                    f"{prior.core_limit:.2f} of the wall wide: wider, it would hold over "
                    f"{100 * cfg.core_share:.0f}% of the SfM observations"
                )
        reason = choice.reason
        if cfg.given_prior:
            prior, apart = place_given_prior(Path(cfg.given_prior), ctx.input(IngestView), poses)
            reason = (
                f"given: the {prior.kind} of {cfg.given_prior}, placed by the shared cameras "
                f"({apart:.2f}% of their path apart); this case's own choice: {choice.kind}"
            )
            ctx.log(f"prior: {reason}")
        save_prior(prior, ctx.out / PRIOR_FILE)
        file = fit.to_file(units).model_dump(mode="json", exclude_none=True)
        file["kind"] = choice.kind
        write_json(ctx.out / CENTERLINE_FILE, file)

        truth = None
        scores: dict[str, float] = {}
        if ctx.case.gt_dir and poses.in_gt_frame:
            from endopipe.stages.io.ground_truth import GroundTruth

            gt_dir = Path(ctx.case.gt_dir)
            truth = (
                GroundTruth(gt_dir).centerline() if (gt_dir / "centerline.json").is_file() else None
            )
            if truth is not None and fit.kind == "tube":
                scores = compare_to_truth(fit, *truth)
        plot_centerline(ctx.out / PLOT_FILE, fit, centres, points, units, truth)
        summary = CenterlineSummary(
            kind=prior.kind,
            prior_reason=reason,
            prior_weight=prior.weight,
            prior_scores=choice.scores,
            reach=reach,
            wall_margin=prior.margin,
            core_limit=prior.core_limit,
            length=fit.length,
            mean_radius=(
                prior.own_radius
                if prior.kind != "tube" or cfg.given_prior
                else float(np.mean(fit.radius))
            ),
            radius_source=fit.radius_source,
            radius_note=fit.radius_note,
            n_points_used=fit.n_points_used,
            n_cameras=len(centres),
            units=units,
            recentred_slices=fit.recentred_slices,
            **{k: v for k, v in scores.items() if k.startswith(("centerline_", "radius_"))},
        )
        if prior.kind == "none":
            ctx.log(
                f"no lumen prior: scene unit {prior.typical_radius:.2f} {units}, rays reach "
                f"{prior.reach:.1f} {units}"
            )
        else:
            ctx.log(
                f"{fit.kind}: length {fit.length:.1f} {units}, mean radius "
                f"{summary.mean_radius:.2f} {units} ({fit.radius_note})"
                + (
                    f"; vs truth: {scores['centerline_mean_dist_pct_of_radius']:.1f}% of "
                    f"radius, radius error {scores['radius_error_pct']:.1f}%"
                    if scores
                    else ""
                )
            )
        return summary


#: A still camera: the scene's typical distance, in the relative units its depth is given in.
STILL_DEPTH = 1.0
#: ... and how far rays reach (a laparoscope's view of tissue spans about 0.5-2x the typical
#: distance; farther, the grid's cells grow with the box).
STILL_REACH = 2.5


def stereo_typical_depth(ingest: IngestView, poses: PosesView) -> float | None:
    """A still stereo camera's typical distance (mm): the median of its matched depth over
    every frame; None without stereo depth or metric poses."""
    if not (poses.metric and ingest.has_stereo):
        return None
    maps = [
        d[d > 0] for i in range(len(ingest.frames)) if (d := ingest.stereo_depth(i)) is not None
    ]
    values = np.concatenate(maps) if maps else np.zeros(0)
    return float(np.median(values)) if len(values) else None


def no_parallax(
    ctx: StageContext[CenterlineConfig],
    centres: np.ndarray,
    stereo_depth: float | None,
    measured_by: str = "the stereo rig",
    why: str = "the camera stands still",
):
    """A still camera saw nothing from two places: no points, no shape to fit. No prior; the
    scene's unit is the stereo depth's typical distance in mm when a rig measured it, else
    the typical depth is 1 (relative depth, said so)."""
    cfg = ctx.config
    typical = stereo_depth if stereo_depth is not None else STILL_DEPTH
    units = "mm" if stereo_depth is not None else "relative"
    scale = cfg.free_scale * typical
    prior = FreePrior(centres.mean(0), scale, STILL_REACH * typical, typical)
    if stereo_depth is not None:
        reason = (
            f"none: {why}, so no parallax places any point; "
            f"{measured_by} measured the typical distance, {typical:.1f} mm"
        )
    else:
        reason = (
            f"none: {why}, so no parallax places any point; depth is relative "
            f"(the typical distance is {STILL_DEPTH:g} unit by definition)"
        )
    ctx.log(f"prior: {reason}")
    save_prior(prior, ctx.out / PRIOR_FILE)
    write_json(
        ctx.out / CENTERLINE_FILE,
        CenterlineFile(kind="none", units=units, points=[], radius=[], arclength=[]).model_dump(
            mode="json", exclude_none=True
        ),
    )
    return CenterlineSummary(
        kind="none",
        prior_reason=reason,
        prior_weight=0.0,
        reach=prior.reach,
        length=0.0,
        mean_radius=scale,
        radius_source="none",
        radius_note="a still camera: no points",
        n_points_used=0,
        n_cameras=len(centres),
        units=units,
    )


def observation_rays(
    ingest: IngestView, poses: PosesView, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frame, camera centre and point of every SfM observation (the sparse model's tracks);
    without tracks, each point with its nearest camera."""
    obs = poses.observations(ingest.index_by_name())
    if obs is not None and len(obs.frame):
        origins = np.array([poses.c2w[int(f)][:3, 3] for f in obs.frame])
        return np.asarray(obs.frame), origins, np.asarray(obs.xyz, np.float64)
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    centres = poses.centres()
    if len(pts) == 0 or len(centres) == 0:
        return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3))
    from scipy.spatial import cKDTree

    nearest = cKDTree(centres).query(pts)[1]
    return np.asarray(poses.registered)[nearest], centres[nearest], pts
