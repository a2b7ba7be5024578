"""The poses stage's SfM path: COLMAP run with each mapper, judged, one kept, its lens re-fitted
when it folds; and sparse points triangulated from poses known another way. pycolmap is
imported inside, when a run needs it."""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import TYPE_CHECKING

from endopipe.pipeline.errors import StageFailed
from endopipe.pipeline.stage import StageContext
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.colmap_model import reconstruction_points
from endopipe.stages.poses.config import PosesConfig
from endopipe.stages.poses.estimate import Estimate
from endopipe.stages.poses.gates import check_registered
from endopipe.stages.poses.lens import LensRefit, fitted_radius_px, lens_folds, unfold
from endopipe.stages.poses.verdict import evidence_from_reconstruction, judge, pick_mapper

if TYPE_CHECKING:
    from endopipe.stages.poses.colmap_sfm import SfmResult


def from_colmap(ingest: IngestView, cfg: PosesConfig, ctx: StageContext[PosesConfig]) -> Estimate:
    """SfM on the ingest's frames: each mapper's model judged on its own, the soundest kept
    (verdict.py), a lens that folds back inside the frame re-fitted as a fisheye."""
    # pycolmap is heavy: only when used
    from endopipe.stages.poses.colmap_sfm import colmap_logging, frame_poses, run_sfm

    known = ingest.intrinsics
    scratch = ctx.out / "colmap"
    index_of = ingest.index_by_name()
    n = len(ingest.frames)

    def doubt(result: SfmResult) -> str | None:
        """Why `result`'s poses are doubtful on their own (None: sound, no second opinion)."""
        if result.reconstruction is None:
            return f"no model: {result.merge}"
        ev = evidence_from_reconstruction(result.reconstruction, index_of)
        alone = judge(ev, n, cfg.verdict, result.mapper)
        return ("; ".join(alone.reasons) or "doubtful") if alone.status != "ok" else None

    try:
        results = run_sfm(ingest, scratch, cfg, known, ctx.progress, ctx.log, doubt)
    finally:
        clean_scratch(scratch, cfg.keep_database, ("images", "masks", "largest", "global"))
    by_mapper = {r.mapper: r for r in results}
    evidence = {
        r.mapper: evidence_from_reconstruction(r.reconstruction, index_of)
        if r.reconstruction is not None
        else None
        for r in results
    }
    if not any(ev is not None and len(ev.index) for ev in evidence.values()):
        check_registered(0, len(ingest.frames), cfg)
    failures = {r.mapper: r.merge for r in results if r.reconstruction is None}
    verdict = pick_mapper(evidence, n, cfg.verdict, failures)
    if cfg.mapper == "auto" and len(results) == 1:
        verdict.others["incremental"] = (
            f"not run: the {results[0].mapper} mapper's poses were sound on their own "
            "(poses.mapper=both runs it too)"
        )
    sfm = by_mapper[verdict.mapper]
    rec, camera, model, c2w = sfm.reconstruction, sfm.camera, sfm.colmap_model, sfm.c2w
    fixed = known is not None and not cfg.refine_known_intrinsics
    refit_info: dict[str, LensRefit] = {}
    if known is None and cfg.unfold_lens and lens_folds(camera, ingest):
        with colmap_logging(cfg.colmap_log):  # its bundle adjustments: no glog lines
            refit = unfold(rec, cfg.refine_principal_point, ctx.log)
        if refit is not None:
            refit_info["lens_refit"] = refit.record
            rec, camera, model = refit.reconstruction, refit.camera, refit.colmap_model
            c2w = frame_poses(rec, index_of)
    xyz, rgb = reconstruction_points(rec)
    timings = {k: round(v, 2) for r in results for k, v in r.timings.items()}
    return Estimate(
        camera=known if fixed else camera,
        colmap_model=model,
        c2w=c2w,
        xyz=xyz,
        rgb=rgb,
        reconstruction=rec,
        intrinsics_kind="fixed" if fixed else ("refined" if known is not None else "estimated"),
        verdict=verdict,
        alternatives={r.mapper: r.c2w for r in results if r is not sfm and r.c2w},
        info={
            "mapper": sfm.mapper,
            "models": len(sfm.model_sizes),
            "model_sizes": sfm.model_sizes,
            "merge": sfm.merge,
            "merged_frames": sfm.merged_frames,
            "mean_reprojection_px": float(rec.compute_mean_reprojection_error()),
            "mean_track_length": float(rec.compute_mean_track_length()),
            "mean_points_per_frame": float(rec.compute_mean_observations_per_reg_image()),
            "timings": timings,
            **refit_info,
        },
        fitted_radius_px=None if known is not None else fitted_radius_px(rec),
    )


def clean_scratch(scratch: Path, keep_database: bool, work: tuple[str, ...]) -> None:
    """Remove COLMAP's scratch folder, or with `keep_database` only its `work` sub-folders (the
    database stays in 02_poses/colmap/ for debugging)."""
    if keep_database:
        for sub in work:
            shutil.rmtree(scratch / sub, ignore_errors=True)
    else:
        shutil.rmtree(scratch, ignore_errors=True)


#: Fewer triangulated points than this are noise, not a wall: keep none.
MIN_TRIANGULATED_POINTS = 10


def triangulate(
    est: Estimate, ingest: IngestView, cfg: PosesConfig, ctx: StageContext[PosesConfig]
) -> None:
    """Sparse points (and tracks in sparse/) from the known poses; without them the centerline
    stage falls back to a default radius. A failure costs the points only, never the stage."""
    from endopipe.stages.poses.colmap_sfm import triangulate_known  # pycolmap: only when used

    scratch = ctx.out / "colmap"
    t = time.perf_counter()
    try:
        rec, xyz, rgb = triangulate_known(
            ingest, scratch, cfg, (est.camera, est.colmap_model), est.c2w, ctx.progress, ctx.log
        )
    except (StageFailed, RuntimeError, ValueError, OSError) as e:
        ctx.log(f"no sparse points: triangulation from the known poses failed ({e})")
        return
    finally:
        clean_scratch(scratch, cfg.keep_database, ("images", "masks", "triangulated"))
    est.info.setdefault("timings", {})["triangulation_s"] = round(time.perf_counter() - t, 2)
    if len(xyz) < MIN_TRIANGULATED_POINTS:
        ctx.log(f"no sparse points: triangulation from the known poses found only {len(xyz)}")
        return
    est.xyz, est.rgb, est.reconstruction = xyz, rgb, rec
    est.info["mean_reprojection_px"] = float(rec.compute_mean_reprojection_error())
    est.info["mean_track_length"] = float(rec.compute_mean_track_length())
