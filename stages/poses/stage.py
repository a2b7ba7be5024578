"""poses: one shared camera and a camera-to-world pose per frame (COLMAP SfM, GT or a file).

Outputs (docs/formats.md): cameras.json (CamerasFile), sparse/ (COLMAP text model), points.ply
(sparse points) and transforms.json (nerfstudio, OpenGL convention). With known poses
(source=gt|file) the sparse points are triangulated from them, so the centerline stage has a wall to
measure. When the input has ground-truth poses (a case folder's gt/ or a data set's pose files, all
through `open_ground_truth`), the reconstruction is moved by the sim3 (Umeyama on camera centres)
that best maps it onto them: it is then in the ground truth's world frame and millimetres ("metric":
true, "aligned_to_gt"), so depth and mesh evaluations compare directly; without ground truth it
stays in COLMAP's units. Settings: config.py; COLMAP: colmap_sfm.py, driven by sfm_estimate.py;
the other sources: sources.py; the sim3 and the stereo scale: alignment.py; what stops a run:
gates.py; the lens (its reach, where it was fitted, its re-fit as a fisheye): lens.py.
"""

from __future__ import annotations

import os
import time

import cv2
import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.pipeline.stage import Stage, StageContext, write_json
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.colmap_model import write_ply, write_text_model
from endopipe.stages.io.ground_truth import poses_by_frame
from endopipe.stages.io.transforms_json import write_transforms_json
from endopipe.stages.metrics.depth import pose_metrics, registered_fraction
from endopipe.stages.poses.alignment import align_to, scale_by_stereo
from endopipe.stages.poses.config import MotionConfig, PosesConfig
from endopipe.stages.poses.estimate import Estimate
from endopipe.stages.poses.gates import check_registered, gate
from endopipe.stages.poses.lens import lens_reach, reach_note
from endopipe.stages.poses.motion import FootageMotion, footage_fps, judge_motion
from endopipe.stages.poses.sfm_estimate import from_colmap, triangulate
from endopipe.stages.poses.sources import (
    from_file,
    from_ground_truth,
    from_known,
    from_one_pair,
    from_still_camera,
)
from endopipe.stages.poses.summary import KnownPosesCheck, PosesSummary
from endopipe.stages.poses.verdict import (
    PoseVerdict,
    evidence_from_reconstruction,
    judge,
    ranges,
)
from endopipe.stages.poses.view import ONE_PAIR_SOURCE, CamerasFile, PosesView

__all__ = ["Poses", "PosesConfig", "PosesSummary"]


class Poses(Stage):
    """Camera poses: COLMAP SfM (seeded, endoscopy-tuned), ground truth, or a user's file."""

    name = "poses"
    needs = ("ingest",)
    # 9: a stereo pair alone; 8: the input's own poses used (source=known) or compared;
    # 7: stereo scale
    version = 9
    Config = PosesConfig
    Summary = PosesSummary
    View = PosesView

    def run(self, ctx: StageContext[PosesConfig]) -> PosesSummary:
        t0 = time.perf_counter()
        cfg = ctx.config
        ingest = ctx.input(IngestView)
        n = len(ingest.frames)
        gt, gt_poses = None, None
        try:
            gt = ingest.ground_truth()
            gt_poses = poses_by_frame(gt, ingest.frames)  # one InputError line if unreadable
        except InputError as e:
            if cfg.source == "gt":
                raise
            ctx.log(f"ground truth ignored: {e}")  # GT only evaluates SfM: not fatal here
        gt_metric = gt is not None and gt.units == "mm"

        motion = None
        if (
            cfg.motion.check and not ingest.one_pair
        ):  # known poses too: the NeRF stage asks whether the scene moves
            motion = footage_motion(ingest, cfg.motion)
            ctx.log(motion.said)
        if ingest.one_pair:
            est = from_one_pair(ingest)
        elif cfg.source == "gt":
            est = from_ground_truth(ingest, gt_poses)
        elif cfg.source == "file":
            est = from_file(ingest, cfg)
        elif cfg.source == "known":
            est = from_known(ingest)
        elif motion is not None and motion.camera == "still":
            est = from_still_camera(ingest, cfg, motion)
        else:
            est = from_colmap(ingest, cfg, ctx)

        if not ingest.one_pair:
            check_registered(len(est.c2w), n, cfg)
        if cfg.source != "colmap" and cfg.triangulate_known and not len(est.xyz) and n > 1:
            triangulate(est, ingest, cfg, ctx)

        aligned = False
        metric = False
        if cfg.source == "gt":
            aligned, metric = True, gt_metric
        elif gt_poses is not None and cfg.align_to_gt and ingest.has_stereo:
            ctx.log("not aligned to the ground truth: the stereo rig gives the scale")
        elif gt_poses is not None and cfg.align_to_gt:
            aligned = align_to(est, gt_poses)
            metric = aligned and gt_metric
        metric_from = "ground truth" if metric else None
        scaled = None
        if ingest.one_pair:  # the world is the left camera in the rig's own millimetres
            metric, metric_from = True, ingest.stereo_measured_by
        elif not metric and ingest.has_stereo:
            scaled, metric_from = scale_by_stereo(est, ingest, motion, ctx.log)
            metric = metric_from is not None
        errors = {}
        if gt_poses is not None and len(set(est.c2w) & set(gt_poses)) >= 3:
            m = pose_metrics(est.c2w, gt_poses)
            errors = {
                "ate_mm": m["ate"],
                # a still truth has no path to be a share of
                "ate_percent_of_path": (
                    m["ate_percent_of_path"] if np.isfinite(m["ate_percent_of_path"]) else None
                ),
                "rre_deg": m["rre_deg"],
                "gt_path_length_mm": m["gt_path_length"],
                "others_ate_percent": {
                    mapper: round(pose_metrics(c2w, gt_poses)["ate_percent_of_path"], 3)
                    for mapper, c2w in est.alternatives.items()
                    if len(set(c2w) & set(gt_poses)) >= 3
                },
            }

        known = known_agreement(est, ingest, cfg.source)
        if known is not None:
            ctx.log(known.said)
        verdict = assess(est, cfg, ingest)
        verdict.motion = motion
        gate(verdict, cfg)
        source = ONE_PAIR_SOURCE if ingest.one_pair else cfg.source
        write_outputs(ctx, ingest, est, source, metric)
        verdict.write(ctx.out / "verdict.json")
        k = est.camera
        summary = PosesSummary(
            source=source,
            registered=len(est.c2w),
            total=n,
            registered_fraction=registered_fraction(len(est.c2w), n),
            unregistered=ranges(sorted(set(range(n)) - set(est.c2w))),
            camera_model=est.colmap_model,
            intrinsics=est.intrinsics_kind,
            fx=k.fx,
            fy=k.fy,
            cx=k.cx,
            cy=k.cy,
            metric=metric,
            metric_from=metric_from,
            stereo_scale=scaled,
            aligned_to_gt=aligned,
            points=len(est.xyz),
            seconds=time.perf_counter() - t0,
            **est.info,
            **errors,
            verdict=verdict.status,
            verdict_reasons="; ".join(verdict.reasons),
            doubtful_frames=ranges(verdict.doubtful_frames()),
            mappers_disagreement_pct=verdict.disagreement_pct,
            depth_drift=verdict.depth_drift,
            lens_reach=lens_reach(k, ingest),
            fitted_radius_px=est.fitted_radius_px,
            motion=motion,
            known_poses=known,
        )
        ctx.log(
            f"registered {summary.registered}/{n} frames ({100 * summary.registered_fraction:.0f}%)"
            + (
                f", ATE {errors['ate_mm']:.3g} mm"
                + (
                    f" ({errors['ate_percent_of_path']:.2f}% of path)"
                    if errors["ate_percent_of_path"] is not None
                    else " (the truth stands still)"
                )
                if errors
                else ""
            )
            + ("; aligned to ground truth (mm)" if aligned and cfg.source != "gt" else "")
        )
        ctx.log(verdict_line(verdict))
        note = reach_note(
            summary.camera_model, summary.lens_reach, summary.intrinsics == "estimated"
        )
        if note is not None:
            ctx.log(note)
        return summary


def assess(est: Estimate, cfg: PosesConfig, ingest: IngestView) -> PoseVerdict:
    """SfM's verdict (chosen with the mapper), a file's judged on its triangulated tracks;
    ground truth is not assessed."""
    if est.verdict is not None:
        return est.verdict
    if cfg.source == "file" and est.reconstruction is not None:
        evidence = evidence_from_reconstruction(est.reconstruction, ingest.index_by_name())
        return judge(evidence, len(ingest.frames), cfg.verdict, "file")
    why = [f"poses from {cfg.source}"]
    return PoseVerdict(status="not assessed", reasons=why, mapper=cfg.source)


def verdict_line(verdict: PoseVerdict) -> str:
    """One log line: the verdict, the mapper kept, why, and what became of the others."""
    doubtful = len(verdict.doubtful())
    if verdict.motion is not None and verdict.motion.camera == "still":
        return f"poses {verdict.status}: " + "; ".join(verdict.reasons)
    line = f"poses {verdict.status}: {verdict.mapper} mapper, {doubtful} doubtful frame(s)"
    if verdict.reasons:
        line += "; " + "; ".join(verdict.reasons)
    for mapper, why in verdict.others.items():
        line += f"; {mapper} mapper {why}"
    return line


def footage_motion(ingest: IngestView, cfg: MotionConfig) -> FootageMotion:
    """Whether the camera moves and the scene holds still, from the ingest's frames in order
    (motion.py); corners are taken only where the ingest's mask allows (not the scope border,
    a highlight or a tool)."""
    frames = ingest.frames
    fps = footage_fps([f.time_s for f in frames], cfg.fps)

    def read(k: int) -> tuple[np.ndarray, np.ndarray | None]:
        i = frames[k].index
        return cv2.cvtColor(ingest.image(i), cv2.COLOR_RGB2GRAY), ingest.mask(i)

    return judge_motion(len(frames), read, fps, cfg)


def known_agreement(est: Estimate, ingest: IngestView, source: str) -> KnownPosesCheck | None:
    """The poses kept beside the input's own (None when it has none, or they are the ones
    kept)."""
    known = ingest.file.known_poses
    if known is None or source == "known":
        return None
    return compare_known(est.c2w, ingest.known_poses() or {}, known.source)


def compare_known(
    ours: dict[int, np.ndarray], known: dict[int, np.ndarray], origin: str
) -> KnownPosesCheck:
    """A path both measure is compared after a sim3 on the camera centres (ATE, % of the known
    path); a still one only by whether the other stands still too."""
    common = sorted(set(ours) & set(known))
    if len(common) < 3:
        return KnownPosesCheck(source=origin, said=f"known poses ({origin}): too few in common")
    path = [np.asarray(known[i])[:3, 3] for i in common]
    known_still = max(float(np.linalg.norm(p - path[0])) for p in path) == 0.0
    ours_still = len({tuple(np.round(ours[i][:3, 3], 9)) for i in common}) == 1
    if known_still or ours_still:
        agree = known_still == ours_still
        said = f"known poses ({origin}): " + ("they stand still" if known_still else "they move")
        mine = "still" if ours_still else "moving"
        said += ", as ours do" if agree else f", unlike ours ({mine})"
        return KnownPosesCheck(source=origin, agree=agree, said=said)
    pct = float(pose_metrics(ours, {i: known[i] for i in common})["ate_percent_of_path"])
    said = (
        f"known poses ({origin}): ours agree with them to {pct:.2f}% of their path (ATE after a "
        f"sim3 on {len(common)} camera centres; they are not ground truth, so this is no score)"
    )
    return KnownPosesCheck(source=origin, ate_percent_of_path=pct, said=said)


def write_outputs(
    ctx: StageContext[PosesConfig], ingest: IngestView, est: Estimate, source: str, metric: bool
) -> None:
    out = ctx.out
    cams = CamerasFile.build(
        est.camera,
        est.c2w,
        len(ingest.frames),
        colmap_model=est.colmap_model,
        metric=metric,
        source=source,
        fitted_radius_px=est.fitted_radius_px,
    )
    write_json(out / "cameras.json", cams.model_dump(mode="json"))
    names = {i: name for name, i in ingest.index_by_name().items()}
    if est.reconstruction is not None:
        (out / "sparse").mkdir()
        est.reconstruction.write_text(str(out / "sparse"))
    else:
        write_text_model(
            out / "sparse",
            est.camera,
            {names[i]: est.c2w[i] for i in sorted(est.c2w)},
            est.colmap_model,
        )
    if len(est.xyz):
        write_ply(out / "points.ply", est.xyz, est.rgb)
    frames = [
        (
            os.path.relpath(ingest.image_path(f.index), out),
            os.path.relpath(ingest.mask_path(f.index), out),
            est.c2w[f.index],
        )
        for f in ingest.frames
        if f.index in est.c2w
    ]
    write_transforms_json(
        out / "transforms.json",
        est.camera,
        frames,
        extra={"endopipe": {"metric": metric, "units": "mm" if metric else "colmap"}},
    )
