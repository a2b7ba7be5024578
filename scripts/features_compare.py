"""SIFT vs XFeat + LighterGlue on an ingested case, each with COLMAP's incremental and global
mapper: registered frames, ATE (% of the GT path, when the case has GT poses), reprojection
error, track length, points and seconds.

Usage (one case per process; OMP_NUM_THREADS=1 keeps it to one core):
    OMP_NUM_THREADS=1 .venv/bin/python scripts/features_compare.py RUN/01_ingest \
        --methods sift,xfeat_rgb,xfeat_clahe --mappers incremental,global --out results.jsonl
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import cv2  # noqa: F401  (must precede pycolmap)
import numpy as np
import pycolmap

from endopipe.stages.camera import Camera
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.colmap_model import c2w_from_cam_from_world, camera_to_colmap
from endopipe.stages.io.ground_truth import poses_by_frame
from endopipe.stages.metrics.depth import pose_metrics
from endopipe.stages.poses.colmap_sfm import (
    colmap_logging,
    extract,
    map_incremental,
    match,
    prepare_images,
)
from endopipe.stages.poses.config import PosesConfig
from endopipe.stages.poses.learned_features import extract_and_match_xfeat, sequential_pairs


@contextmanager
def _no_progress(_label: str, _total: int | None) -> Iterator[Callable[..., None]]:
    yield lambda *_a, **_k: None


def build_database(
    method: str, ingest: IngestView, scratch: Path, cfg: PosesConfig, intrinsics: Camera | None
) -> tuple[Path, float]:
    """Features + verified matches of `method` in scratch/database.db; returns it and seconds."""
    scratch.mkdir(parents=True, exist_ok=True)
    database = scratch / "database.db"
    database.unlink(missing_ok=True)
    names = list(ingest.index_by_name())
    t = time.perf_counter()
    image_dir, mask_dir = prepare_images(ingest, names, scratch, cfg)
    if method == "sift":
        extract(database, image_dir, mask_dir, names, cfg, intrinsics)
        match(database, cfg, len(names))
    else:
        model, params = (
            camera_to_colmap(intrinsics) if intrinsics is not None else (cfg.camera_model, None)
        )
        extract_and_match_xfeat(
            database,
            image_dir,
            mask_dir,
            names,
            sequential_pairs(len(names), cfg.sequential_overlap, cfg.quadratic_overlap),
            model,
            params,
            cfg.seed,
            pixels_dir=ingest.frames_dir if method == "xfeat_rgb" else image_dir,
        )
    return database, time.perf_counter() - t


def global_options(intrinsics_known: bool, image_path: Path) -> pycolmap.GlobalPipelineOptions:
    """GLOMAP, single-threaded and seeded, CPU only; intrinsics fixed when known."""
    options = pycolmap.GlobalPipelineOptions()
    options.num_threads = 1
    options.random_seed = 0
    options.image_path = str(image_path)
    mapper = options.mapper
    mapper.num_threads = 1
    mapper.random_seed = 0
    mapper.image_path = str(image_path)
    mapper.rotation_averaging.random_seed = 0
    mapper.global_positioning.random_seed = 0
    mapper.retriangulation.random_seed = 0
    mapper.global_positioning.use_gpu = False
    mapper.bundle_adjustment.ceres.use_gpu = False
    if intrinsics_known:
        mapper.bundle_adjustment.refine_focal_length = False
        mapper.bundle_adjustment.refine_principal_point = False
        mapper.bundle_adjustment.refine_extra_params = False
    return options


def run_mapper(
    mapper: str,
    database: Path,
    ingest: IngestView,
    scratch: Path,
    cfg: PosesConfig,
    intrinsics: Camera | None,
) -> tuple[list[pycolmap.Reconstruction], float]:
    """Every model the mapper finds (on a copy of the database) and its seconds."""
    copy = scratch / f"{mapper}.db"
    shutil.copy(database, copy)
    n = len(ingest.frames)
    t = time.perf_counter()
    if mapper == "incremental":
        models = map_incremental(copy, ingest.frames_dir, cfg, intrinsics, n, _no_progress)
    else:
        out = scratch / "global"
        shutil.rmtree(out, ignore_errors=True)
        out.mkdir()
        pycolmap.set_random_seed(0)
        options = global_options(intrinsics is not None, ingest.frames_dir)
        models = list(pycolmap.global_mapping(copy, ingest.frames_dir, out, options).values())
    return [m for m in models if m.num_reg_images() > 0], time.perf_counter() - t


def summarise(
    models: list[pycolmap.Reconstruction], ingest: IngestView, gt: dict[int, np.ndarray] | None
) -> dict[str, Any]:
    """Figures of the largest model (ATE only with GT poses)."""
    if not models:
        return {"registered": 0, "models": []}
    models = sorted(models, key=lambda r: r.num_reg_images(), reverse=True)
    rec = models[0]
    index_of = ingest.index_by_name()
    c2w = {
        index_of[im.name]: c2w_from_cam_from_world(im.cam_from_world().matrix())
        for im in rec.images.values()
        if im.has_pose and im.name in index_of
    }
    row: dict[str, Any] = {
        "registered": len(c2w),
        "models": [m.num_reg_images() for m in models],
        "reproj_px": rec.compute_mean_reprojection_error(),
        "track_len": rec.compute_mean_track_length(),
        "points": rec.num_points3D(),
    }
    if gt is not None and len(set(c2w) & set(gt)) >= 3:
        metrics = pose_metrics(c2w, gt)
        row["ate_pct"] = metrics["ate_percent_of_path"]
        row["rre_deg"] = metrics["rre_deg"]
    return row


def database_stats(database: Path) -> dict[str, float]:
    with pycolmap.Database.open(database) as db:
        images = db.read_all_images()
        keypoints = [db.num_keypoints_for_image(im.image_id) for im in images]
        return {
            "keypoints_mean": float(np.mean(keypoints)) if keypoints else 0.0,
            "verified_pairs": int(db.num_verified_image_pairs()),
            "inlier_matches": int(db.num_inlier_matches()),
        }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ingest", type=Path, help="an ingested case's 01_ingest folder")
    parser.add_argument("--methods", default="sift,xfeat_rgb,xfeat_clahe")
    parser.add_argument("--mappers", default="incremental,global")
    parser.add_argument("--scratch", type=Path, default=Path("/tmp/features_compare"))
    parser.add_argument("--out", type=Path, help="append one JSON line per result")
    args = parser.parse_args()
    ingest = IngestView(args.ingest)
    cfg = PosesConfig()
    intrinsics = ingest.intrinsics
    gt = poses_by_frame(ingest.ground_truth(), ingest.frames)
    case = args.ingest.resolve().parent.name
    for method in args.methods.split(","):
        scratch = args.scratch / case / method
        with colmap_logging(False):
            database, feature_s = build_database(method, ingest, scratch, cfg, intrinsics)
            stats = database_stats(database)
            for mapper in args.mappers.split(","):
                models, mapping_s = run_mapper(mapper, database, ingest, scratch, cfg, intrinsics)
                row = {
                    "case": case,
                    "frames": len(ingest.frames),
                    "method": method,
                    "mapper": mapper,
                    "features_s": round(feature_s, 1),
                    "mapping_s": round(mapping_s, 1),
                    **stats,
                    **summarise(models, ingest, gt),
                }
                print(json.dumps(row), flush=True)
                if args.out:
                    with args.out.open("a") as f:
                        f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
