"""poses: one shared camera and a camera-to-world pose per frame (COLMAP SfM, GT or a file).

Outputs (DESIGN §3): cameras.json (CamerasFile), sparse/ (COLMAP text model), points.ply (sparse
points) and transforms.json (nerfstudio, OpenGL convention). With known poses (source=gt|file)
the sparse points are triangulated from them, so the centerline stage has a wall to measure.
When the case has ground-truth poses, the reconstruction is moved by the sim3 (Umeyama on camera
centres) that best maps it onto them: it is then in the ground truth's world frame and
millimetres ("metric": true, "aligned_to_gt"), so depth and mesh evaluations compare directly;
without ground truth it stays in COLMAP's units.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field

from endopipe.pipeline.errors import ConfigError, InputError, StageFailed
from endopipe.pipeline.stage import Stage, StageConfig, StageContext, Summary, write_json
from endopipe.stages.camera import Camera, apply_sim3, umeyama
from endopipe.stages.ingest.stage import IngestView
from endopipe.stages.io.colmap_model import (
    CameraModel,
    PoseSet,
    read_colmap_model,
    read_transforms_json,
    trailing_number,
    write_ply,
    write_text_model,
    write_transforms_json,
)
from endopipe.stages.io.ground_truth import GroundTruth
from endopipe.stages.metrics.depth import pose_metrics, registered_fraction
from endopipe.stages.poses.view import CamerasFile, PosesView

CameraModelName = Literal["SIMPLE_RADIAL", "RADIAL", "SIMPLE_PINHOLE", "PINHOLE", "OPENCV"]


class PosesConfig(StageConfig):
    source: Literal["colmap", "gt", "file"] = Field(
        "colmap",
        description="Where poses come from: COLMAP SfM on the frames, the case's gt/poses.json, "
        "or poses.file.",
    )
    file: str | None = Field(
        None,
        description="For source=file: a COLMAP model folder (text or binary) or a transforms.json "
        "(OpenGL convention). Images are matched to frames by name, else by the number in it.",
    )
    min_registered: float = Field(
        0.7, ge=0, le=1, description="Fail when fewer than this share of the frames get a pose."
    )
    align_to_gt: bool = Field(
        True,
        description="With ground-truth poses in the case, move the reconstruction onto them "
        "(sim3 on camera centres): GT world frame, millimetres, metric=true.",
    )
    seed: int = Field(0, ge=0, description="Seed of every random choice (RANSAC, mapper).")
    num_threads: int = Field(
        1,
        ge=-1,
        description="Matching and mapper threads. 1 makes two runs agree (COLMAP is "
        "deterministic only single-threaded); -1 = all cores.",
    )
    clahe: bool = Field(
        True, description="Extract features on CLAHE-equalised grey images (more SIFT on mucosa)."
    )
    clahe_clip_limit: float = Field(2.0, gt=0, description="CLAHE contrast clip limit.")
    clahe_tiles: int = Field(8, ge=1, description="CLAHE tiles per image side.")
    use_masks: bool = Field(
        True, description="Ignore features outside the ingest masks (scope border, speculars)."
    )
    mask_grow_px: int = Field(
        3,
        ge=0,
        description="Grow the specular holes of the mask by this much for feature extraction "
        "(synthetic colon, 60 frames: ATE 1.46% of the path with 0, 0.25% with 5 px in total).",
    )
    sift_peak_threshold: float = Field(
        0.002,
        gt=0,
        description="SIFT peak threshold (COLMAP default 0.0067): lower finds features on "
        "low-contrast tissue.",
    )
    sift_max_features: int = Field(4096, ge=64, description="At most this many SIFT features.")
    sift_domain_size_pooling: bool = Field(
        True, description="Domain-size pooling of SIFT descriptors (more robust, CPU only)."
    )
    matcher: Literal["sequential", "exhaustive"] = Field(
        "sequential", description="sequential: each frame with its next neighbours (video order)."
    )
    sequential_overlap: int = Field(
        15, ge=1, description="Sequential matching: neighbours each frame is matched with."
    )
    quadratic_overlap: bool = Field(
        True, description="Sequential matching: also match frames 2^k apart."
    )
    init_min_num_inliers: int = Field(
        30, ge=8, description="Mapper: inliers the initial pair needs (COLMAP default 100)."
    )
    abs_pose_min_num_inliers: int = Field(
        15, ge=6, description="Mapper: inliers a new frame needs to register (COLMAP default 30)."
    )
    init_min_tri_angle: float = Field(
        2.0,
        gt=0,
        description="Mapper: triangulation angle (deg) of the initial pair (COLMAP default 16; "
        "endoscopes move little between frames).",
    )
    min_model_size: int = Field(
        10,
        ge=2,
        description="Mapper: models with fewer frames are dropped (when there are several).",
    )
    camera_model: CameraModelName = Field(
        "SIMPLE_RADIAL",
        description="COLMAP camera model estimated when the intrinsics are unknown.",
    )
    refine_known_intrinsics: bool = Field(
        False,
        description="Let bundle adjustment refine known intrinsics (default: keep them fixed).",
    )
    refine_principal_point: bool = Field(
        False, description="When intrinsics are refined, refine the principal point too."
    )
    merge_models: bool = Field(
        True,
        description="When COLMAP leaves frames out (several models), continue the largest model "
        "with relaxed registration to add them.",
    )
    triangulate_known: bool = Field(
        True,
        description="With source=gt|file: triangulate sparse points from the known poses (the "
        "centerline stage measures the lumen radius from them; a file's own points are kept).",
    )
    keep_database: bool = Field(
        False, description="Keep COLMAP's database.db in 02_poses/colmap/ (for debugging)."
    )
    colmap_log: bool = Field(False, description="Show COLMAP's own log on stderr.")


class PosesSummary(Summary):
    source: str
    registered: int
    total: int
    registered_fraction: float
    unregistered: str
    camera_model: str
    intrinsics: str
    fx: float
    fy: float
    cx: float
    cy: float
    metric: bool
    aligned_to_gt: bool
    points: int
    seconds: float


@dataclass
class Estimate:
    """Poses from any source, before alignment and writing."""

    camera: CameraModel
    intrinsics: Camera
    c2w: dict[int, np.ndarray]
    xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    rgb: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.uint8))
    reconstruction: Any = None  # pycolmap.Reconstruction: SfM's, or the known poses' tracks
    info: dict[str, Any] = field(default_factory=dict)
    intrinsics_kind: str = "fixed"


class Poses(Stage):
    """Camera poses: COLMAP SfM (seeded, endoscopy-tuned), ground truth, or a user's file."""

    name = "poses"
    needs = ("ingest",)
    version = 2  # 2: sparse points triangulated from known poses
    Config = PosesConfig

    @classmethod
    def view(cls, folder: Path) -> PosesView:
        return PosesView(folder)

    def run(self, ctx: StageContext) -> PosesSummary:
        t0 = time.perf_counter()
        cfg: PosesConfig = ctx.config  # type: ignore[assignment]
        ingest: IngestView = ctx.input("ingest")
        n = len(ingest.frames)
        gt = GroundTruth(ingest.gt_dir) if ingest.gt_dir is not None else None
        gt_poses = None
        if gt is not None and gt.has_poses():
            try:
                gt_poses = ground_truth_poses(ingest, gt)
            except InputError as e:
                if cfg.source == "gt":
                    raise
                ctx.log(f"ground truth ignored: {e}")  # GT only evaluates SfM: not fatal here
        gt_metric = gt is not None and gt.units == "mm"

        if cfg.source == "gt":
            est = from_ground_truth(ingest, gt_poses)
        elif cfg.source == "file":
            est = from_file(ingest, cfg)
        else:
            est = from_colmap(ingest, cfg, ctx)

        check_registered(len(est.c2w), n, cfg)
        if cfg.source != "colmap" and cfg.triangulate_known and not len(est.xyz):
            triangulate(est, ingest, cfg, ctx)

        aligned = False
        metric = False
        if cfg.source == "gt":
            aligned, metric = True, gt_metric
        elif gt_poses is not None and cfg.align_to_gt:
            aligned = align_to(est, gt_poses)
            metric = aligned and gt_metric
        errors = {}
        if gt_poses is not None and len(set(est.c2w) & set(gt_poses)) >= 3:
            m = pose_metrics(est.c2w, gt_poses)
            errors = {
                "ate_mm": m["ate"],
                "ate_percent_of_path": m["ate_percent_of_path"],
                "rre_deg": m["rre_deg"],
                "gt_path_length_mm": m["gt_path_length"],
            }

        write_outputs(ctx, ingest, est, cfg.source, metric)
        k = est.intrinsics
        summary = PosesSummary(
            source=cfg.source,
            registered=len(est.c2w),
            total=n,
            registered_fraction=registered_fraction(len(est.c2w), n),
            unregistered=ranges(sorted(set(range(n)) - set(est.c2w))),
            camera_model=est.camera.model,
            intrinsics=est.intrinsics_kind,
            fx=k.fx,
            fy=k.fy,
            cx=k.cx,
            cy=k.cy,
            metric=metric,
            aligned_to_gt=aligned,
            points=len(est.xyz),
            seconds=time.perf_counter() - t0,
            **est.info,
            **errors,
        )
        ctx.log(
            f"registered {summary.registered}/{n} frames ({100 * summary.registered_fraction:.0f}%)"
            + (
                f", ATE {errors['ate_mm']:.3g} mm ({errors['ate_percent_of_path']:.2f}% of path)"
                if errors
                else ""
            )
            + ("; aligned to ground truth (mm)" if aligned and cfg.source != "gt" else "")
        )
        return summary


def ground_truth_poses(ingest: IngestView, gt: GroundTruth) -> dict[int, np.ndarray]:
    """GT camera-to-world per endopipe frame index (via source_index)."""
    try:
        poses = gt.poses()
        if any(p.shape != (4, 4) or not np.isfinite(p).all() for p in poses):
            raise ValueError("every pose must be a finite 4x4 matrix")
    except (ValueError, KeyError, TypeError, OSError) as e:
        raise InputError(f"cannot read {gt.dir / 'poses.json'}: {e}") from None
    return {f.index: poses[f.source_index] for f in ingest.frames if f.source_index < len(poses)}


def from_ground_truth(ingest: IngestView, gt_poses: dict[int, np.ndarray] | None) -> Estimate:
    if gt_poses is None:
        raise InputError(
            "poses.source=gt but the case has no gt/poses.json; use poses.source=colmap, or give "
            "an endopipe case folder with ground truth"
        )
    if ingest.intrinsics is None:
        raise InputError(
            "poses.source=gt needs known intrinsics (intrinsics.json in the case, or "
            "--intrinsics FILE)"
        )
    k = ingest.intrinsics
    return Estimate(
        camera=CameraModel.from_intrinsics(k),
        intrinsics=k,
        c2w=dict(gt_poses),
        info={"models": 0},
    )


def clean_scratch(scratch: Path, keep_database: bool, work: tuple[str, ...]) -> None:
    """Remove COLMAP's scratch folder, or with `keep_database` only its `work` sub-folders (the
    database stays in 02_poses/colmap/ for debugging)."""
    if keep_database:
        for sub in work:
            shutil.rmtree(scratch / sub, ignore_errors=True)
    else:
        shutil.rmtree(scratch, ignore_errors=True)


def from_colmap(ingest: IngestView, cfg: PosesConfig, ctx: StageContext) -> Estimate:
    from endopipe.stages.poses.colmap_sfm import (
        run_sfm,  # pycolmap is heavy: import only when SfM runs
    )

    known = ingest.intrinsics
    scratch = ctx.out / "colmap"
    try:
        sfm = run_sfm(ingest, scratch, cfg, known, ctx.progress, ctx.log)
    finally:
        clean_scratch(scratch, cfg.keep_database, ("images", "masks", "largest"))
    if sfm.reconstruction is None:
        check_registered(0, len(ingest.frames), cfg)
    rec = sfm.reconstruction
    fixed = known is not None and not cfg.refine_known_intrinsics
    from endopipe.stages.io.colmap_model import reconstruction_points

    xyz, rgb = reconstruction_points(rec)
    return Estimate(
        camera=sfm.camera,
        intrinsics=known if fixed else sfm.camera.intrinsics(),
        c2w=sfm.c2w,
        xyz=xyz,
        rgb=rgb,
        reconstruction=rec,
        intrinsics_kind="fixed" if fixed else ("refined" if known is not None else "estimated"),
        info={
            "models": len(sfm.model_sizes),
            "model_sizes": sfm.model_sizes,
            "merge": sfm.merge,
            "merged_frames": sfm.merged_frames,
            "mean_reprojection_px": float(rec.compute_mean_reprojection_error()),
            "mean_track_length": float(rec.compute_mean_track_length()),
            "mean_points_per_frame": float(rec.compute_mean_observations_per_reg_image()),
            **{k: round(v, 2) for k, v in sfm.timings.items()},
        },
    )


#: Fewer triangulated points than this are noise, not a wall: keep none.
MIN_TRIANGULATED_POINTS = 10


def triangulate(est: Estimate, ingest: IngestView, cfg: PosesConfig, ctx: StageContext) -> None:
    """Sparse points (and tracks in sparse/) from the known poses; without them the centerline
    stage falls back to a default radius. A failure costs the points only, never the stage."""
    from endopipe.stages.poses.colmap_sfm import (
        triangulate_known,  # pycolmap is heavy: import only when used
    )

    scratch = ctx.out / "colmap"
    t = time.perf_counter()
    try:
        rec, xyz, rgb = triangulate_known(
            ingest, scratch, cfg, est.camera, est.c2w, ctx.progress, ctx.log
        )
    except (StageFailed, RuntimeError, ValueError, OSError) as e:
        ctx.log(f"no sparse points: triangulation from the known poses failed ({e})")
        return
    finally:
        clean_scratch(scratch, cfg.keep_database, ("images", "masks", "triangulated"))
    est.info["triangulation_s"] = round(time.perf_counter() - t, 2)
    if len(xyz) < MIN_TRIANGULATED_POINTS:
        ctx.log(f"no sparse points: triangulation from the known poses found only {len(xyz)}")
        return
    est.xyz, est.rgb, est.reconstruction = xyz, rgb, rec
    est.info["mean_reprojection_px"] = float(rec.compute_mean_reprojection_error())
    est.info["mean_track_length"] = float(rec.compute_mean_track_length())


def from_file(ingest: IngestView, cfg: PosesConfig) -> Estimate:
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
    c2w = match_frames(poses, ingest)
    if not c2w:
        some = ", ".join(list(poses.c2w)[:3])
        raise InputError(
            f"none of the {len(poses.c2w)} images in {path} ({some}, ...) matches a frame; name "
            "them like 01_ingest/frames (000000.png) or like the input's files"
        )
    w, h = ingest.width, ingest.height
    if poses.camera is not None:
        cam = poses.camera
        if abs(cam.width / cam.height - w / h) > 0.01:
            raise InputError(
                f"the camera in {path} is {cam.width}x{cam.height} but the frames are {w}x{h}; "
                "give poses estimated on these frames"
            )
        camera = cam.scaled(w, h)
        kind = "from file"
    elif ingest.intrinsics is not None:
        camera = CameraModel.from_intrinsics(ingest.intrinsics)
        kind = "fixed"
    else:
        raise InputError(
            f"{path} gives no intrinsics and none are known; add fl_x, fl_y, cx, cy, w, h to it or "
            "pass --intrinsics FILE"
        )
    xyz = poses.xyz
    return Estimate(
        camera=camera,
        intrinsics=ingest.intrinsics if kind == "fixed" else camera.intrinsics(),
        c2w=c2w,
        xyz=xyz,
        rgb=poses.rgb,
        intrinsics_kind=kind,
        info={"models": 1, "file": str(path)},
    )


def match_frames(poses: PoseSet, ingest: IngestView) -> dict[int, np.ndarray]:
    """Map a file's image names to endopipe frames: the strategy matching the most frames wins.

    By endopipe name (000000.png), by the input's own file names (image folders), or by the
    number in the name read as the frame's position in the input (source_index).
    """
    by_name = {Path(f.file).stem: f.index for f in ingest.frames}
    by_source_index = {f.source_index: f.index for f in ingest.frames}
    source_names = input_file_names(ingest)
    by_source_name = {
        Path(source_names[f.source_index]).stem: f.index
        for f in ingest.frames
        if f.source_index < len(source_names)
    }
    candidates = []
    for table in (by_name, by_source_name):
        candidates.append(
            {table[Path(n).stem]: c for n, c in poses.c2w.items() if Path(n).stem in table}
        )
    numbers = {n: trailing_number(n) for n in poses.c2w}
    if len(set(numbers.values())) == len(numbers):
        candidates.append(
            {by_source_index[v]: poses.c2w[n] for n, v in numbers.items() if v in by_source_index}
        )
    return max(candidates, key=len)


def input_file_names(ingest: IngestView) -> list[str]:
    """The input's image file names in source order (empty for a video input)."""
    from endopipe.stages.io.sources import list_images

    data = json.loads((ingest.folder / "frames.json").read_text())
    src = Path(data.get("source", {}).get("path", ""))
    return [p.name for p in list_images(src)] if src.is_dir() else []


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
        hint = "gt/poses.json has too few poses for these frames"
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
    est.c2w = {i: apply_sim3(s, R, t, c) for i, c in est.c2w.items()}
    if len(est.xyz):
        est.xyz = s * est.xyz @ R.T + t
    if est.reconstruction is not None:
        import pycolmap

        est.reconstruction.transform(pycolmap.Sim3d(s, pycolmap.Rotation3d(R), t))
    est.info["sim3_scale"] = float(s)
    return True


def write_outputs(
    ctx: StageContext, ingest: IngestView, est: Estimate, source: str, metric: bool
) -> None:
    out = ctx.out
    cams = CamerasFile.build(
        est.intrinsics,
        est.c2w,
        len(ingest.frames),
        model=est.camera.model,
        params=est.camera.params,
        metric=metric,
        source=source,
    )
    write_json(out / "cameras.json", cams.model_dump(mode="json"))
    names = {f.index: Path(f.file).name for f in ingest.frames}
    if est.reconstruction is not None:
        (out / "sparse").mkdir()
        est.reconstruction.write_text(str(out / "sparse"))
    else:
        write_text_model(
            out / "sparse", est.camera, {names[i]: est.c2w[i] for i in sorted(est.c2w)}
        )
    if len(est.xyz):
        write_ply(out / "points.ply", est.xyz, est.rgb)
    frames = []
    for f in ingest.frames:
        if f.index in est.c2w:
            rel = lambda p: os.path.relpath(ingest.folder / p, out)  # noqa: E731
            frames.append((rel(f.file), rel(f.mask), est.c2w[f.index]))
    write_transforms_json(
        out / "transforms.json",
        est.camera,
        frames,
        extra={"endopipe": {"metric": metric, "units": "mm" if metric else "colmap"}},
    )


def ranges(indices: list[int]) -> str:
    """[0, 1, 2, 7, 9, 10] -> '0-2, 7, 9-10'."""
    parts: list[str] = []
    start = prev = None
    for i in [*indices, None]:
        if i is not None and prev is not None and i == prev + 1:
            prev = i
            continue
        if start is not None:
            parts.append(f"{start}" if start == prev else f"{start}-{prev}")
        start = prev = i
    return ", ".join(parts)
