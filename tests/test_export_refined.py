"""endopipe export of a case whose poses the NeRF refined, seen through a barrel lens: the exported
depth, unprojected through the exported camera (its lens) at the exported pose, lies on the
exported mesh; cameras.json's unrefined poses, or the camera without its lens, put it off.

A tiny synthetic colon (6 frames, 96x80, OpenCV k1 -0.3, k2 0.06) runs ingest..mesh through the
CLI with ground-truth poses and `nerf.pose_refine.mode=on` at a high learning rate from the first
step, so that 40 steps move the poses by degrees (about 12 s on one core).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from endopipe import export
from endopipe.cli import build_pipeline, main
from endopipe.export import ExportResult
from endopipe.export.endonerf import MAX_LENS_SHIFT_PX, lens_shift_px
from endopipe.pipeline.errors import EndopipeError
from endopipe.stages.camera import Camera, backproject
from endopipe.stages.io.colmap_model import read_colmap_model
from endopipe.stages.io.transforms_json import TransformsFile, read_transforms_json
from endopipe.stages.mesh.view import MeshView
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import PosesView
from endopipe.stages.surface.raycast import point_to_surface
from endopipe.synth import SynthConfig, generate_case

REFINE = [
    "poses.source=gt",
    "poses.triangulate_known=false",
    "centerline.prior=tube",  # no sparse points: the tube at its default radius
    "ingest.drop_duplicates=false",
    "ingest.drop_blurred=false",
    "nerf.field.tensorf.res_init=24",
    "nerf.field.tensorf.res_final=40",
    "nerf.sampling.n_coarse=32",
    "nerf.sampling.n_fine=16",
    "nerf.train.batch_rays=256",
    "nerf.train.steps=40",
    "nerf.train.time_budget_s=null",
    "nerf.train.threads=1",
    "nerf.train.holdout_every=0",
    "nerf.pose_refine.mode=on",
    "nerf.pose_refine.start=0",
    "nerf.pose_refine.warmup=0",
    "nerf.pose_refine.lr=0.01",
    "nerf.pose_refine.heldout_steps=0",
    "depth.preview=false",
    "depth.colour=false",
    "mesh.evaluate=false",
]


@pytest.fixture(scope="module")
def refined_case(tmp_path_factory: pytest.TempPathFactory) -> Path:
    src = tmp_path_factory.mktemp("refined_input") / "barrel"
    generate_case(src, SynthConfig(frames=6, width=96, height=80, lens="barrel", noise_std=0.0))
    wd = tmp_path_factory.mktemp("refined_wd")
    sets = [a for s in REFINE for a in ("--set", s)]
    assert main(["run", str(src), "--workdir", str(wd), "--until", "mesh", "--quiet", *sets]) == 0
    return wd / "barrel"


def export_case(case: Path, fmt: str, out: Path) -> ExportResult:
    return export.export_case(case, fmt, out, folders=build_pipeline().folders(case))


def mesh_distances(
    folder: Path, camera: Camera, c2w: dict[str, np.ndarray], mesh: trimesh.Trimesh
) -> np.ndarray:
    """Distance to `mesh` of every exported depth pixel of a nerfstudio export, unprojected
    through `camera` at `c2w` (by image file name)."""
    out = []
    for frame in TransformsFile.load(folder / "transforms.json").frames:
        assert frame.depth_file_path is not None
        depth = np.load(folder / frame.depth_file_path) / 1000.0  # nerfstudio's default factor
        pts = backproject(camera, depth, c2w[Path(frame.file_path).name])[depth > 0]
        out.append(point_to_surface(pts, mesh.vertices, mesh.faces))
    return np.concatenate(out)


def test_refined_depth_reprojects_onto_the_exported_mesh(refined_case: Path, tmp_path: Path):
    """75% of the exported depth lies within one TSDF voxel of the exported mesh (0.13 mm
    measured, voxel 0.23 mm); at cameras.json's unrefined poses 0.89 mm, without the lens
    2.2 mm."""
    case = refined_case
    refined = NerfView(case / "04_nerf").refined_cameras
    assert refined is not None and refined.movement["median_rotation_deg"] > 1.0  # 2.5 measured
    export_case(case, "nerfstudio", tmp_path / "ns")
    export_case(case, "ply", tmp_path / "ply")
    exported = read_transforms_json(tmp_path / "ns" / "transforms.json")  # the one reader
    given = PosesView(case / "02_poses")
    camera = exported.camera
    assert camera == given.intrinsics and camera.model == "opencv" and camera.distorted
    assert json.loads((tmp_path / "ns" / "export.json").read_text())["poses_refined"]

    mesh = trimesh.load(tmp_path / "ply" / "mesh.ply", process=False)
    bound = MeshView(case / "06_mesh").summary.voxel_size
    ours = mesh_distances(tmp_path / "ns", camera, exported.c2w, mesh)
    assert len(ours) > 5000 and np.percentile(ours, 75) < bound, np.percentile(ours, 75)
    unrefined = {f"{i:06d}.png": c2w for i, c2w in given.c2w.items()}
    wrong_poses = mesh_distances(tmp_path / "ns", camera, unrefined, mesh)
    assert np.percentile(wrong_poses, 75) > 2 * bound, np.percentile(wrong_poses, 75)
    wrong_lens = mesh_distances(tmp_path / "ns", camera.pinhole(), exported.c2w, mesh)
    assert np.percentile(wrong_lens, 75) > 2 * bound, np.percentile(wrong_lens, 75)

    # the PLY export agrees: its fused points lie on the mesh, its cameras at the exported poses
    cloud = trimesh.load(tmp_path / "ply" / "points.ply", process=False)
    fused = point_to_surface(np.asarray(cloud.vertices), mesh.vertices, mesh.faces)
    assert np.percentile(fused, 75) < bound
    cameras = trimesh.load(tmp_path / "ply" / "cameras.ply", process=False)
    centres = np.array([exported.c2w[name][:3, 3] for name in sorted(exported.c2w)])
    assert np.allclose(cameras.vertices, centres, atol=1e-5)


def test_colmap_export_carries_the_lens_and_the_refined_poses(refined_case: Path, tmp_path):
    export_case(refined_case, "colmap", tmp_path / "colmap")
    export_case(refined_case, "nerfstudio", tmp_path / "ns")
    model = read_colmap_model(tmp_path / "colmap")
    exported = read_transforms_json(tmp_path / "ns" / "transforms.json")
    assert model.colmap_model == "OPENCV" and model.camera == exported.camera
    assert sorted(model.c2w) == sorted(exported.c2w)
    for name, c2w in exported.c2w.items():
        assert np.allclose(model.c2w[name], c2w, atol=1e-9)


def test_endonerf_refuses_a_lens_it_cannot_carry(refined_case: Path, tmp_path: Path) -> None:
    with pytest.raises(EndopipeError, match="pinhole-only.*export nerfstudio or colmap"):
        export_case(refined_case, "endonerf", tmp_path / "endo")
    assert not (tmp_path / "endo").exists()


def test_lens_shift_decides_what_endonerf_takes() -> None:
    k = Camera(width=96, height=80, fx=60.0, fy=60.0, cx=47.5, cy=39.5)
    assert lens_shift_px(k) == 0.0
    slight = k.model_copy(update={"model": "opencv", "dist": [-1e-4, 0.0, 0.0, 0.0]})
    barrel = k.model_copy(update={"model": "opencv", "dist": [-0.3, 0.06, 0.0, 0.0]})
    assert 0.0 < lens_shift_px(slight) < MAX_LENS_SHIFT_PX < 5.0 < lens_shift_px(barrel)
