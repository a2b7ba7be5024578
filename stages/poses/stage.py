"""poses: one shared camera and a camera-to-world pose per frame (COLMAP SfM, GT or a file).

Outputs (docs/formats.md): cameras.json (CamerasFile), sparse/ (COLMAP text model), points.ply
(sparse points) and transforms.json (nerfstudio, OpenGL convention). With known poses
(source=gt|file) the sparse points are triangulated from them, so the centerline stage has a wall to
measure. When the input has ground-truth poses (a case folder's gt/ or a data set's pose files, all
through `open_ground_truth`), the reconstruction is moved by the sim3 (Umeyama on camera centres)
that best maps it onto them: it is then in the ground truth's world frame and millimetres ("metric":
true, "aligned_to_gt"), so depth and mesh evaluations compare directly; without ground truth it
stays in COLMAP's units. Settings: config.py; COLMAP: colmap_sfm.py; the lens (its reach, where
it was fitted, its re-fit as a fisheye): lens.py.
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from endopipe.pipeline.errors import ConfigError, InputError, StageFailed
from endopipe.pipeline.stage import Stage, StageContext, write_json
from endopipe.stages.camera import Camera, apply_sim3, umeyama
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.colmap_model import (
    PoseSet,
    camera_to_colmap,
    keep_images,
    read_colmap_model,
    reconstruction_points,
    write_ply,
    write_text_model,
)
from endopipe.stages.io.ground_truth import poses_by_frame
from endopipe.stages.io.name_numbers import file_number
from endopipe.stages.io.transforms_json import read_transforms_json, write_transforms_json
from endopipe.stages.metrics.depth import pose_metrics, registered_fraction
from endopipe.stages.poses.config import MotionConfig, PosesConfig
from endopipe.stages.poses.estimate import Estimate
from endopipe.stages.poses.lens import (
    LensRefit,
    fitted_radius_px,
    lens_folds,
    lens_reach,
    reach_note,
    unfold,
)
from endopipe.stages.poses.motion import FootageMotion, footage_fps, judge_motion
from endopipe.stages.poses.stereo_scale import stereo_scale
from endopipe.stages.poses.summary import KnownPosesCheck, PosesSummary, StereoScale
from endopipe.stages.poses.verdict import (
    FrameVerdict,
    PoseVerdict,
    evidence_from_reconstruction,
    judge,
    pick_mapper,
    ranges,
)
from endopipe.stages.poses.view import CamerasFile, PosesView, reconstruction_observations

if TYPE_CHECKING:
    from endopipe.stages.poses.colmap_sfm import SfmResult

__all__ = ["Poses", "PosesConfig", "PosesSummary"]


class Poses(Stage):
    """Camera poses: COLMAP SfM (seeded, endoscopy-tuned), ground truth, or a user's file."""

    name = "poses"
    needs = ("ingest",)
    version = 8  # 8: the input's own poses used (source=known) or compared; 7: stereo scale
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
        if cfg.motion.check:  # known poses too: the NeRF stage asks whether the scene moves
            motion = footage_motion(ingest, cfg.motion)
            ctx.log(motion.said)
        if cfg.source == "gt":
            est = from_ground_truth(ingest, gt_poses)
        elif cfg.source == "file":
            est = from_file(ingest, cfg)
        elif cfg.source == "known":
            est = from_known(ingest)
        elif motion is not None and motion.camera == "still":
            est = from_still_camera(ingest, cfg, motion)
        else:
            est = from_colmap(ingest, cfg, ctx)

        check_registered(len(est.c2w), n, cfg)
        if cfg.source != "colmap" and cfg.triangulate_known and not len(est.xyz):
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
        if not metric and ingest.has_stereo:
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
        write_outputs(ctx, ingest, est, cfg.source, metric)
        verdict.write(ctx.out / "verdict.json")
        k = est.camera
        summary = PosesSummary(
            source=cfg.source,
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


def gate(verdict: PoseVerdict, cfg: PosesConfig) -> None:
    """With verdict.on_doubtful=refuse, doubtful poses stop the run with what to try."""
    if verdict.status != "doubtful" or cfg.verdict.on_doubtful != "refuse":
        return
    raise StageFailed(
        f"poses doubtful: {'; '.join(verdict.reasons)}; try known intrinsics (--intrinsics "
        "FILE), a smaller --set ingest.stride, another --set poses.mapper, or --set "
        "poses.verdict.on_doubtful=warn to go on"
    )


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


def from_still_camera(ingest: IngestView, cfg: PosesConfig, motion: FootageMotion) -> Estimate:
    """One fixed pose for every frame: a still camera has no path, and SfM would make one of
    the tissue's motion. Without known intrinsics the lens is assumed (nothing here could
    measure it) and the summary says so; there are no sparse points (no parallax)."""
    known = ingest.intrinsics
    camera = known if known is not None else assumed_camera(ingest, cfg.motion.assumed_hfov_deg)
    kind = "fixed" if known is not None else "assumed"
    c2w = {f.index: np.eye(4) for f in ingest.frames}
    lens = (
        ""
        if known is not None
        else (
            f"; intrinsics assumed ({cfg.motion.assumed_hfov_deg:g} deg horizontal field of view: "
            "give --intrinsics FILE for the real lens)"
        )
    )
    verdict = PoseVerdict(
        status="ok",
        reasons=[f"{motion.label}: one fixed pose for all {len(c2w)} frames{lens}", motion.said],
        mapper="still camera",
        frames=[FrameVerdict(index=i, status="ok") for i in sorted(c2w)],
    )
    return Estimate(
        camera=camera,
        colmap_model=camera_to_colmap(camera)[0],
        c2w=c2w,
        intrinsics_kind=kind,
        verdict=verdict,
        info={"models": 1, "mapper": "still camera"},
    )


def assumed_camera(ingest: IngestView, hfov_deg: float) -> Camera:
    """A pinhole with the principal point at the centre and the given horizontal field of view."""
    w, h = ingest.width, ingest.height
    f = 0.5 * w / np.tan(np.radians(hfov_deg) / 2)
    return Camera(width=w, height=h, fx=f, fy=f, cx=(w - 1) / 2, cy=(h - 1) / 2)


def from_ground_truth(ingest: IngestView, gt_poses: dict[int, np.ndarray] | None) -> Estimate:
    if gt_poses is None:
        raise InputError(
            "poses.source=gt but the input has no ground-truth poses (gt/poses.json, or a data "
            "set's pose files); use poses.source=colmap"
        )
    if ingest.intrinsics is None:
        raise InputError(
            "poses.source=gt needs known intrinsics (intrinsics.json in the case, or "
            "--intrinsics FILE)"
        )
    k = ingest.intrinsics
    return Estimate(
        camera=k, colmap_model=camera_to_colmap(k)[0], c2w=dict(gt_poses), info={"models": 0}
    )


def from_known(ingest: IngestView) -> Estimate:
    """The poses the input came with (not ground truth), as they are: a data set's own account
    of where its camera was, used when SfM cannot say (a still scope, tissue that moves)."""
    known = ingest.known_poses()
    if not known:
        raise InputError(
            "poses.source=known but the input came with no poses of its own (EndoNeRF's "
            "poses_bounds.npy, SCARED's frame_data/); use poses.source=colmap"
        )
    if ingest.intrinsics is None:
        raise InputError(
            "poses.source=known needs known intrinsics (--intrinsics FILE, or the data set's "
            "calibration)"
        )
    k = ingest.intrinsics
    return Estimate(
        camera=k,
        colmap_model=camera_to_colmap(k)[0],
        c2w=dict(known),
        intrinsics_kind="fixed",
        info={"models": 0},
    )


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


def clean_scratch(scratch: Path, keep_database: bool, work: tuple[str, ...]) -> None:
    """Remove COLMAP's scratch folder, or with `keep_database` only its `work` sub-folders (the
    database stays in 02_poses/colmap/ for debugging)."""
    if keep_database:
        for sub in work:
            shutil.rmtree(scratch / sub, ignore_errors=True)
    else:
        shutil.rmtree(scratch, ignore_errors=True)


def from_colmap(ingest: IngestView, cfg: PosesConfig, ctx: StageContext[PosesConfig]) -> Estimate:
    # pycolmap is heavy: only when used
    from endopipe.stages.poses.colmap_sfm import frame_poses, run_sfm

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


def from_file(ingest: IngestView, cfg: PosesConfig) -> Estimate:
    """Poses from a COLMAP model or a transforms.json. A model's tracks are kept for the frames
    it poses (the SfM-point depth and the lumen fit need them), unless its camera has another
    resolution than the frames."""
    if not cfg.file:
        raise ConfigError(
            "poses.source=file needs --set poses.file=PATH (a COLMAP model folder or "
            "transforms.json)"
        )
    path = Path(cfg.file).expanduser()
    if not path.exists():
        raise InputError(
            f"poses.file not found: {path}; give a COLMAP model folder or transforms.json"
        )
    if path.is_dir() and (path / "transforms.json").is_file():
        if not any(path.glob("cameras.*")) and not (path / "sparse").is_dir():
            path = path / "transforms.json"
    poses = read_transforms_json(path) if path.is_file() else read_colmap_model(path)
    frame_of = match_names(list(poses.c2w), ingest)
    c2w = {i: poses.c2w[name] for name, i in frame_of.items()}
    if not c2w:
        some = ", ".join(list(poses.c2w)[:3])
        raise InputError(
            f"none of the {len(poses.c2w)} images in {path} ({some}, ...) matches a frame; name "
            "them like 01_ingest/frames (000000.png) or like the input's files"
        )
    w, h = ingest.width, ingest.height
    if poses.camera is not None and poses.colmap_model is not None:
        cam = poses.camera
        if abs(cam.width / cam.height - w / h) > 0.01:
            raise InputError(
                f"the camera in {path} is {cam.width}x{cam.height} but the frames are {w}x{h}; "
                "give poses estimated on these frames"
            )
        camera, model = (
            (cam if (cam.width, cam.height) == (w, h) else cam.scaled(w, h)),
            (poses.colmap_model),
        )
        kind = "from file"
    elif ingest.intrinsics is not None:
        camera, model = ingest.intrinsics, camera_to_colmap(ingest.intrinsics)[0]
        kind = "fixed"
    else:
        raise InputError(
            f"{path} gives no intrinsics and none are known; add fl_x, fl_y, cx, cy, w, h to it or "
            "pass --intrinsics FILE"
        )
    est = Estimate(
        camera=camera,
        colmap_model=model,
        c2w=c2w,
        xyz=poses.xyz,
        rgb=poses.rgb,
        intrinsics_kind=kind,
        info={"models": 1, "file": str(path)},
    )
    rec = poses.reconstruction
    model_size = (poses.camera.width, poses.camera.height) if poses.camera else None
    if rec is not None and rec.num_points3D() and model_size == (w, h):
        names = {i: name for name, i in ingest.index_by_name().items()}
        keep_images(rec, {name: names[i] for name, i in frame_of.items()})
        est.xyz, est.rgb = reconstruction_points(rec)
        est.reconstruction = rec
        if kind == "from file":  # the lens may have been estimated: where its tracks reach
            est.fitted_radius_px = fitted_radius_px(rec)
    return est


def match_frames(poses: PoseSet, ingest: IngestView) -> dict[int, np.ndarray]:
    """A file's poses by endopipe frame index (see `match_names`)."""
    return {i: poses.c2w[name] for name, i in match_names(list(poses.c2w), ingest).items()}


def match_names(names: list[str], ingest: IngestView) -> dict[str, int]:
    """Map a file's image names to endopipe frames: the strategy matching the most frames wins.

    By endopipe name (000000.png), by the input's own file names (image folders), or by the
    number in the name read as the frame's position in the input (source_index).
    """
    by_name = ingest.index_by_stem()
    by_source_index = ingest.index_by_source_index()
    by_source_name = ingest.index_by_source_stem()
    candidates = []
    for table in (by_name, by_source_name):
        candidates.append({n: table[Path(n).stem] for n in names if Path(n).stem in table})
    numbers = {n: file_number(n) for n in names}
    if len(set(numbers.values())) == len(numbers):
        candidates.append(
            {n: by_source_index[v] for n, v in numbers.items() if v in by_source_index}
        )
    return max(candidates, key=len)


def check_registered(registered: int, total: int, cfg: PosesConfig) -> None:
    """The quality gate: one line with the ratio and what to try."""
    frac = registered_fraction(registered, total)
    if frac >= cfg.min_registered and registered >= min(3, total):
        return
    ratio = f"{registered}/{total} frames ({100 * frac:.0f}%) < {100 * cfg.min_registered:.0f}%"
    if cfg.source == "colmap":
        hint = (
            "try a smaller --set ingest.stride, known intrinsics (--intrinsics FILE), or "
            "--set poses.source=file"
        )
    elif cfg.source == "file":
        hint = f"{cfg.file} gives poses for too few frames; check its image names"
    else:
        hint = "the ground truth has too few poses for these frames"
    raise StageFailed(f"registered {ratio}: {hint} (or lower --set poses.min_registered)")


def align_to(est: Estimate, gt_poses: dict[int, np.ndarray]) -> bool:
    """Move poses, points and the COLMAP model by the sim3 that maps camera centres onto GT."""
    common = sorted(set(est.c2w) & set(gt_poses))
    if len(common) < 3:
        return False
    src = np.array([est.c2w[i][:3, 3] for i in common])
    dst = np.array([gt_poses[i][:3, 3] for i in common])
    if np.linalg.norm(src - src.mean(0), axis=1).max() < 1e-12:
        return False
    s, R, t = umeyama(src, dst)
    transform(est, s, R, t)
    est.info["sim3_scale"] = float(s)
    return True


def scale_by_stereo(
    est: Estimate, ingest: IngestView, motion: FootageMotion | None, log: Callable[[str], None]
) -> tuple[StereoScale | None, str | None]:
    """Millimetres from the stereo depth: SfM poses scaled by it at their points; a still
    camera's one pose is its own frame, already in the stereo depth's millimetres. (None,
    None) when the points and the stereo depth share too few pixels."""
    if est.reconstruction is None:
        if motion is not None and motion.camera == "still":
            log(
                f"metric: a still camera, its depth measured by {ingest.stereo_measured_by}; "
                "its frame and depth are in millimetres"
            )
            return None, "stereo"
        log("metric scale: no SfM points to scale by the stereo depth; the poses stay unscaled")
        return None, None
    obs = reconstruction_observations(est.reconstruction, ingest.index_by_name(), set(est.c2w))
    if obs is not None:
        obs.resize((est.camera.width, est.camera.height), (ingest.width, ingest.height))
    scaled = stereo_scale(obs, est.c2w, ingest.stereo_depth, (ingest.height, ingest.width))
    if scaled is None:
        log("metric scale: too few SfM points have stereo depth; the poses stay unscaled")
        return None, None
    transform(est, scaled.mm_per_unit, np.eye(3), np.zeros(3))
    log(
        f"metric scale from stereo: {scaled.mm_per_unit:.4g} mm per SfM unit, from "
        f"{scaled.points} points (median deviation {100 * scaled.spread:.1f}%)"
    )
    return scaled, "stereo"


def transform(est: Estimate, s: float, R: np.ndarray, t: np.ndarray) -> None:
    """Move poses, points and the COLMAP model by the similarity x -> s R x + t."""
    est.c2w = {i: apply_sim3(s, R, t, c) for i, c in est.c2w.items()}
    if len(est.xyz):
        est.xyz = s * est.xyz @ R.T + t
    if est.reconstruction is not None:
        import pycolmap

        est.reconstruction.transform(pycolmap.Sim3d(s, pycolmap.Rotation3d(R), t))


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
