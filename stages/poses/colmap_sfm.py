"""Structure from motion with pycolmap: features, matches, incremental mapping, merging, and
triangulation from known poses.

Small functions over a scratch folder (database + CLAHE images), as in pycolmap's examples.
Every pycolmap failure on bad input becomes one StageFailed line, never a traceback.
Tuned for endoscopy (measured on C3VD): CLAHE-equalised grey images, a low SIFT peak threshold
with domain-size pooling, sequential matching and a mapper that accepts small baselines.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import cv2  # must precede pycolmap (see endopipe.stages/__init__.py)
import numpy as np
import pycolmap

from endopipe.pipeline.errors import StageFailed
from endopipe.stages.camera import Camera
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.colmap_model import (
    c2w_from_cam_from_world,
    camera_from_pycolmap,
    camera_to_colmap,
    reconstruction_points,
)
from endopipe.stages.poses.config import PosesConfig
from endopipe.stages.poses.estimate import ProgressFactory


@dataclass
class SfmResult:
    """One mapper's reconstruction (its largest model, after merging) and how it got there."""

    mapper: str  # "incremental" | "global"
    reconstruction: pycolmap.Reconstruction | None  # None when no model was found
    camera: Camera | None  # the model's camera, its lens included
    colmap_model: str | None  # ... and the COLMAP model it was estimated as
    #: endopipe frame index -> camera-to-world 4x4 (OpenCV), registered frames only
    c2w: dict[int, np.ndarray]
    model_sizes: list[int]
    merge: str
    merged_frames: int
    timings: dict[str, float] = field(default_factory=dict)


def run_sfm(
    ingest: IngestView,
    scratch: Path,
    cfg: PosesConfig,
    intrinsics: Camera | None,
    progress: ProgressFactory,
    log: Callable[[str], None] = lambda _: None,
    doubt: Callable[[SfmResult], str | None] = lambda _: None,
) -> list[SfmResult]:
    """Features -> matches, once -> the mappers of `cfg.mapper` on those matches (both: global
    and incremental; auto: global, then incremental only when `doubt` finds the global result
    doubtful and says why). One SfmResult per mapper run; the poses stage keeps one."""
    scratch.mkdir(parents=True, exist_ok=True)
    database = scratch / "database.db"
    names = list(ingest.index_by_name())
    timings: dict[str, float] = {}
    with colmap_logging(cfg.colmap_log), progress("features + matching", 2) as advance:
        t = time.perf_counter()
        image_dir, mask_dir = prepare_images(ingest, names, scratch, cfg)
        extract(database, image_dir, mask_dir, names, cfg, intrinsics)
        timings["features_s"] = time.perf_counter() - t
        advance(info=f"{len(names)} frames")
        t = time.perf_counter()
        match(database, cfg, len(names))
        timings["matching_s"] = time.perf_counter() - t
        advance(info=f"{num_verified_pairs(database)} verified pairs")
    alone = cfg.mapper in ("global", "incremental")
    mappers = [cfg.mapper] if alone else ["global", "incremental"]
    results: list[SfmResult] = []
    for mapper in mappers:
        if cfg.mapper == "auto" and results:
            why = doubt(results[0])
            if why is None:
                log(f"{results[0].mapper} poses sound on their own: no second opinion")
                break
            log(f"{results[0].mapper} poses doubtful ({why}): the {mapper} mapper too")
        t = time.perf_counter()
        run = sfm_global if mapper == "global" else sfm_incremental
        try:
            result = run(ingest, database, scratch, cfg, intrinsics, progress)
        except StageFailed as e:  # with another mapper to try, one failure is not the stage's
            if alone:
                raise
            result = SfmResult(mapper, None, None, None, {}, [], str(e), 0)
        result.timings = {**timings, f"{mapper}_mapping_s": time.perf_counter() - t}
        log(f"{mapper} mapper: models {result.model_sizes}; {result.merge}")
        results.append(result)
    return results


def sfm_incremental(
    ingest: IngestView,
    database: Path,
    scratch: Path,
    cfg: PosesConfig,
    intrinsics: Camera | None,
    progress: ProgressFactory,
) -> SfmResult:
    """COLMAP's incremental mapper, then the other models merged into the largest."""
    n = len(ingest.frames)
    with colmap_logging(cfg.colmap_log):
        models = map_incremental(database, ingest.frames_dir, cfg, intrinsics, n, progress)
    if not models:  # no initial pair: the quality gate reports 0 registered frames
        return SfmResult("incremental", None, None, None, {}, [], "no initial image pair", 0)
    models.sort(key=lambda r: r.num_reg_images(), reverse=True)
    sizes = [r.num_reg_images() for r in models]
    largest = models[0]
    merge, merged = "nothing to merge: every frame is in one model", 0
    if largest.num_reg_images() < n:
        if cfg.merge_models:
            with colmap_logging(cfg.colmap_log):
                extended = continue_mapping(
                    database, largest, ingest.frames_dir, scratch, cfg, intrinsics, n, progress
                )
            merged = max(0, extended.num_reg_images() - largest.num_reg_images())
            others = f" from {len(models) - 1} other model(s)" if len(models) > 1 else ""
            merge = (
                f"continued the largest model ({largest.num_reg_images()} frames) with relaxed "
                f"registration: +{merged} frame(s){others}"
            )
            if merged > 0:
                largest = extended
        else:
            merge = "not tried (poses.merge_models=false); kept the largest model"
    return _result("incremental", largest, ingest, sizes, merge, merged)


def sfm_global(
    ingest: IngestView,
    database: Path,
    scratch: Path,
    cfg: PosesConfig,
    intrinsics: Camera | None,
    progress: ProgressFactory,
) -> SfmResult:
    """The global mapper (GLOMAP: rotation averaging, then all positions at once): no chain of
    registrations, so no drift of scale along the path (bench cavity from its video: ATE 0.11%
    of the path where the incremental mapper drifts to 17.7%)."""
    out = scratch / "global"
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    pycolmap.set_random_seed(cfg.seed)
    with (
        colmap_logging(cfg.colmap_log),
        colmap_errors("global mapping"),
        progress("global mapping", None) as advance,
    ):
        models = pycolmap.global_mapping(
            database, ingest.frames_dir, out, global_options(cfg, intrinsics, ingest.frames_dir)
        )
        advance(0, info=f"{len(models)} model(s)")
    models = sorted(
        (m for m in models.values() if m.num_reg_images() > 0),
        key=lambda r: r.num_reg_images(),
        reverse=True,
    )
    if not models:
        return SfmResult("global", None, None, None, {}, [], "no model", 0)
    sizes = [r.num_reg_images() for r in models]
    return _result("global", models[0], ingest, sizes, "kept the largest model", 0)


def global_options(
    cfg: PosesConfig, intrinsics: Camera | None, image_path: Path
) -> pycolmap.GlobalPipelineOptions:
    """The seeded global mapper on the CPU; intrinsics stay fixed when they are known."""
    options = pycolmap.GlobalPipelineOptions()
    options.image_path = str(image_path)
    options.num_threads = cfg.num_threads
    options.random_seed = cfg.seed
    options.min_model_size = cfg.min_model_size
    mapper = options.mapper
    mapper.num_threads = cfg.num_threads
    mapper.random_seed = cfg.seed
    mapper.image_path = str(image_path)
    mapper.rotation_averaging.random_seed = cfg.seed
    mapper.global_positioning.random_seed = cfg.seed
    mapper.global_positioning.use_gpu = False
    mapper.retriangulation.random_seed = cfg.seed
    ba = mapper.bundle_adjustment
    ba.ceres.use_gpu = False
    refine = intrinsics is None or cfg.refine_known_intrinsics
    ba.refine_focal_length = refine
    ba.refine_principal_point = refine and cfg.refine_principal_point
    ba.refine_extra_params = refine
    return options


def _result(
    mapper: str,
    rec: pycolmap.Reconstruction,
    ingest: IngestView,
    sizes: list[int],
    merge: str,
    merged: int,
) -> SfmResult:
    camera, model = camera_from_pycolmap(next(iter(rec.cameras.values())))
    c2w = frame_poses(rec, ingest.index_by_name())
    return SfmResult(mapper, rec, camera, model, c2w, sizes, merge, merged)


def frame_poses(rec: pycolmap.Reconstruction, index_of: dict[str, int]) -> dict[int, np.ndarray]:
    """endopipe frame index -> camera-to-world 4x4 of every posed image of `rec`."""
    return {
        index_of[image.name]: c2w_from_cam_from_world(image.cam_from_world().matrix())
        for image in rec.images.values()
        if image.has_pose and image.name in index_of
    }


def triangulate_known(
    ingest: IngestView,
    scratch: Path,
    cfg: PosesConfig,
    camera: tuple[Camera, str],
    c2w: dict[int, np.ndarray],
    progress: ProgressFactory,
    log: Callable[[str], None] = lambda _: None,
) -> tuple[pycolmap.Reconstruction, np.ndarray, np.ndarray]:
    """Sparse points from fixed poses and a fixed camera (poses.source=gt|file).

    `camera` is the known camera and the COLMAP model to give it as. The same features and
    matches as SfM, then COLMAP's point triangulator with the poses held:
    the centerline stage measures the lumen radius from these points, as it does from SfM's.
    Returns the model (poses, camera, tracks), xyz (N,3) and rgb (N,3 uint8), in c2w's frame.
    """
    scratch.mkdir(parents=True, exist_ok=True)
    database = scratch / "database.db"
    frame_of = ingest.index_by_name()
    names = list(frame_of)
    with colmap_logging(cfg.colmap_log), progress("triangulation from known poses", 3) as advance:
        t = time.perf_counter()
        image_dir, mask_dir = prepare_images(ingest, names, scratch, cfg)
        extract(database, image_dir, mask_dir, names, cfg, None, camera=camera)
        advance(info=f"{len(names)} frames")
        match(database, cfg, len(names))
        advance(info=f"{num_verified_pairs(database)} verified pairs")
        with pycolmap.Database.open(database) as db:
            cameras, images = db.read_all_cameras(), db.read_all_images()
        rec = pycolmap.Reconstruction()
        for cam in cameras:  # one (CameraMode.SINGLE): the known camera, with the database's id
            rec.add_camera_with_trivial_rig(cam)
        for db_image in images:  # the database's ids and names; unposed frames stay unregistered
            image = pycolmap.Image(
                name=db_image.name, camera_id=db_image.camera_id, image_id=db_image.image_id
            )
            pose = c2w.get(frame_of.get(db_image.name, -1))
            if pose is None:
                rec.add_image_with_trivial_frame(image)
            else:
                rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(np.linalg.inv(pose)[:3]))
        options = mapper_options(cfg, None, ingest.frames_dir)
        options.ba_refine_focal_length = False  # the camera is known: only the points move
        options.ba_refine_principal_point = False
        options.ba_refine_extra_params = False
        pycolmap.set_random_seed(cfg.seed)
        with colmap_errors("triangulation"):
            rec = pycolmap.triangulate_points(
                rec,
                database,
                ingest.frames_dir,  # colours from the RGB frames
                scratch / "triangulated",
                clear_points=True,
                options=options,
                refine_intrinsics=False,
            )
        xyz, rgb = reconstruction_points(rec)
        advance(info=f"{len(xyz)} points")
    log(
        f"triangulated {len(xyz)} points from {len(c2w)} known poses in "
        f"{time.perf_counter() - t:.1f} s"
    )
    return rec, xyz, rgb


def prepare_images(
    ingest: IngestView, names: list[str], scratch: Path, cfg: PosesConfig
) -> tuple[Path, Path]:
    """Grey (CLAHE-equalised) images for SIFT and COLMAP-named masks (`<image>.png`, 0 = ignore)."""
    image_dir, mask_dir = scratch / "images", scratch / "masks"
    image_dir.mkdir(exist_ok=True)
    mask_dir.mkdir(exist_ok=True)
    clahe = cv2.createCLAHE(cfg.clahe_clip_limit, (cfg.clahe_tiles, cfg.clahe_tiles))
    for i, name in enumerate(names):
        grey = cv2.cvtColor(ingest.image(i), cv2.COLOR_RGB2GRAY)
        if cfg.clahe:
            grey = clahe.apply(grey)
        mask = feature_mask(ingest, i, cfg.mask_grow_px)
        cv2.imwrite(str(image_dir / name), grey)
        cv2.imwrite(
            str(mask_dir / f"{name}.png"), mask if cfg.use_masks else np.full_like(mask, 255)
        )
    return image_dir, mask_dir


def feature_mask(ingest: IngestView, i: int, grow_px: int) -> np.ndarray:
    """The ingest mask with its specular holes grown by `grow_px`: keypoints on the glow around
    a highlight move with the light, not with the tissue (the scope border is not grown)."""
    mask = ingest.mask(i)
    if grow_px <= 0:
        return mask
    fov = ingest.fov()
    holes = ((mask == 0) & (fov > 0)).astype(np.uint8)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow_px + 1, 2 * grow_px + 1))
    grown = cv2.dilate(holes, kernel) > 0
    return np.where(grown, 0, mask).astype(np.uint8)


def extract(
    database: Path,
    image_dir: Path,
    mask_dir: Path,
    names: list[str],
    cfg: PosesConfig,
    intrinsics: Camera | None,
    camera: tuple[Camera, str] | None = None,
) -> None:
    """SIFT on every image, one shared camera (the smallest COLMAP model of the known lens).

    `camera` gives that camera with its own COLMAP model (a pose file's may be another one).
    """
    reader = pycolmap.ImageReaderOptions()
    reader.mask_path = str(mask_dir)
    known = None
    if camera is not None:
        known = camera_to_colmap(*camera)
    elif intrinsics is not None:
        known = camera_to_colmap(intrinsics)
    if known is not None:
        reader.camera_model = known[0]
        reader.camera_params = ",".join(f"{v:.17g}" for v in known[1])
    else:
        reader.camera_model = cfg.camera_model
        reader.default_focal_length_factor = cfg.focal_factor
    options = pycolmap.FeatureExtractionOptions()
    options.num_threads = -1
    options.use_gpu = False
    options.max_image_size = 100_000  # never resize: ingest chose the working resolution
    options.sift.max_num_features = cfg.sift_max_features
    options.sift.peak_threshold = cfg.sift_peak_threshold
    options.sift.domain_size_pooling = cfg.sift_domain_size_pooling
    pycolmap.set_random_seed(cfg.seed)
    with colmap_errors("feature extraction"):
        # import first: ids then follow frame order (the parallel extractor writes new images in
        # completion order, which would make ids, pairs and so the poses vary between runs)
        pycolmap.Database.open(database).close()
        pycolmap.import_images(
            database,
            image_dir,
            camera_mode=pycolmap.CameraMode.SINGLE,
            image_names=names,
            options=reader,
        )
        pycolmap.extract_features(
            database,
            image_dir,
            image_names=names,
            camera_mode=pycolmap.CameraMode.SINGLE,
            reader_options=reader,
            extraction_options=options,
            device=pycolmap.Device.cpu,
        )
    with pycolmap.Database.open(database) as db:
        if db.num_images() < len(names):
            raise StageFailed(
                f"COLMAP read only {db.num_images()} of {len(names)} frames for feature "
                "extraction; check the frames in 01_ingest (re-run with --from ingest)"
            )


def match(database: Path, cfg: PosesConfig, n_images: int) -> None:
    """Sequential (video order) or exhaustive matching with seeded geometric verification."""
    matching = pycolmap.FeatureMatchingOptions()
    # Geometric verification draws from per-thread random states: with several threads the
    # verified matches (and so the poses) can differ between two runs.
    matching.num_threads = cfg.num_threads
    matching.use_gpu = False
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = cfg.seed
    pycolmap.set_random_seed(cfg.seed)
    with colmap_errors("feature matching"):
        if cfg.matcher == "exhaustive":
            pycolmap.match_exhaustive(
                database,
                matching_options=matching,
                verification_options=verification,
                device=pycolmap.Device.cpu,
            )
        else:
            pairing = pycolmap.SequentialPairingOptions()
            pairing.overlap = min(cfg.sequential_overlap, max(1, n_images - 1))
            pairing.quadratic_overlap = cfg.quadratic_overlap
            pairing.num_threads = cfg.num_threads
            pycolmap.match_sequential(
                database,
                matching_options=matching,
                pairing_options=pairing,
                verification_options=verification,
                device=pycolmap.Device.cpu,
            )


def num_verified_pairs(database: Path) -> int:
    with pycolmap.Database.open(database) as db:
        return int(db.num_verified_image_pairs())


def mapper_options(
    cfg: PosesConfig, intrinsics: Camera | None, image_path: Path
) -> pycolmap.IncrementalPipelineOptions:
    """The seeded incremental mapper; intrinsics stay fixed when they are known."""
    options = pycolmap.IncrementalPipelineOptions()
    options.image_path = str(image_path)  # colours of the sparse points come from the RGB frames
    options.num_threads = cfg.num_threads
    options.random_seed = cfg.seed
    options.mapper.num_threads = cfg.num_threads
    options.mapper.random_seed = cfg.seed
    options.triangulation.random_seed = cfg.seed
    options.min_model_size = cfg.min_model_size
    options.mapper.init_min_num_inliers = cfg.init_min_num_inliers
    options.mapper.abs_pose_min_num_inliers = cfg.abs_pose_min_num_inliers
    options.mapper.init_min_tri_angle = cfg.init_min_tri_angle
    refine = intrinsics is None or cfg.refine_known_intrinsics
    options.ba_refine_focal_length = refine
    options.ba_refine_principal_point = refine and cfg.refine_principal_point
    options.ba_refine_extra_params = refine
    options.mapper.abs_pose_refine_focal_length = refine
    options.mapper.abs_pose_refine_extra_params = refine
    return options


def map_incremental(
    database: Path,
    image_path: Path,
    cfg: PosesConfig,
    intrinsics: Camera | None,
    n_images: int,
    progress: ProgressFactory,
) -> list[pycolmap.Reconstruction]:
    """Incremental mapping; returns every model found (possibly several, possibly none)."""
    options = mapper_options(cfg, intrinsics, image_path)
    manager = pycolmap.ReconstructionManager()
    _run_pipeline(options, database, manager, n_images, progress, "mapping")
    return [manager.get(i) for i in range(manager.size()) if manager.get(i).num_reg_images() > 0]


def continue_mapping(
    database: Path,
    model: pycolmap.Reconstruction,
    image_path: Path,
    scratch: Path,
    cfg: PosesConfig,
    intrinsics: Camera | None,
    n_images: int,
    progress: ProgressFactory,
) -> pycolmap.Reconstruction:
    """Re-run the mapper seeded with `model`, with relaxed registration, to add the rest.

    Frames of the other models share matches with the largest one in the database, so those
    the relaxed absolute-pose step can place join it; the others stay unregistered.
    """
    seed_dir = scratch / "largest"
    if seed_dir.exists():
        shutil.rmtree(seed_dir)
    seed_dir.mkdir()
    model.write(seed_dir)
    manager = pycolmap.ReconstructionManager()
    manager.read(seed_dir)
    options = mapper_options(cfg, intrinsics, image_path)
    options.multiple_models = False
    options.min_num_matches = max(6, options.min_num_matches // 2)
    options.mapper.abs_pose_min_num_inliers = max(8, cfg.abs_pose_min_num_inliers // 2)
    options.mapper.abs_pose_min_inlier_ratio = 0.1
    options.mapper.max_reg_trials = 6
    options.mapper.abs_pose_max_error = 16.0
    _run_pipeline(
        options, database, manager, n_images, progress, "merging", start=model.num_reg_images()
    )
    return manager.get(0)


def _run_pipeline(
    options: pycolmap.IncrementalPipelineOptions,
    database: Path,
    manager: pycolmap.ReconstructionManager,
    n_images: int,
    progress: ProgressFactory,
    label: str,
    start: int = 0,
) -> None:
    """Run an IncrementalPipeline; a registration callback feeds the progress bar."""
    # COLMAP's global PRNG is per thread and also drawn from during extraction and matching:
    # re-seed right before mapping so the mapper's choices do not depend on what ran before
    pycolmap.set_random_seed(options.random_seed)
    with colmap_errors(label), pycolmap.Database.open(database) as db:
        pipeline = pycolmap.IncrementalPipeline(options, db, manager)
        with progress(label, n_images) as advance:
            state = {"shown": 0}
            if start:
                advance(start, info="seed model")
                state["shown"] = start

            def on_image() -> None:
                if manager.size() == 0:
                    return
                idx = manager.size() - 1
                reg = manager.get(idx).num_reg_images()
                if reg > state["shown"]:
                    advance(reg - state["shown"], info=f"model {idx + 1}: {reg} frames")
                    state["shown"] = reg
                else:
                    advance(0, info=f"model {idx + 1}: {reg} frames")

            for cb in (
                pycolmap.IncrementalPipelineCallback.INITIAL_IMAGE_PAIR_REG_CALLBACK,
                pycolmap.IncrementalPipelineCallback.NEXT_IMAGE_REG_CALLBACK,
            ):
                pipeline.add_callback(cb.value, on_image)
            pipeline.run()


@contextmanager
def colmap_errors(step: str) -> Iterator[None]:
    """pycolmap's exceptions on bad input as one StageFailed line."""
    try:
        yield
    except (RuntimeError, ValueError, OSError) as e:
        text = str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__
        raise StageFailed(
            f"COLMAP {step} failed: {text[:200]}; check the frames in 01_ingest or try "
            "--set poses.source=file"
        ) from None


@contextmanager
def colmap_logging(verbose: bool) -> Iterator[None]:
    """COLMAP logs every step to stderr: nothing unless asked. Its errors come back as
    exceptions (`colmap_errors`) or as our own lines on what it found; logged, they are glog
    lines beside ours ("Cannot continue with empty pose graph" where we say "no model", and
    "Stopping thread..." on a Ctrl-C or SIGTERM)."""
    before = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 0 if verbose else 3
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = before
