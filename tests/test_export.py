"""endopipe export: every format round-trips the poses of cameras.json (and the depth, masks).

Built on the hand-made case of handmade_case.make_case: cameras advancing along +z towards the wall
z = WALL_Z, with exact depth, so what is read back can be compared with what was written.
"""

from __future__ import annotations

import filecmp
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from endopipe import export
from endopipe.cli import build_pipeline, main
from endopipe.export import ExportResult
from endopipe.export.endonerf import (
    ENDONERF_AXES,
    c2w_from_llff,
    endonerf_depth_scale,
    llff_matrix,
    read_endonerf,
)
from endopipe.pipeline.errors import EndopipeError
from endopipe.stages.io.colmap_model import read_colmap_model
from endopipe.stages.io.transforms_json import OPENGL_FROM_OPENCV, read_transforms_json
from endopipe.stages.poses.view import CamerasFile
from tests.handmade_case import UNREGISTERED, WALL_Z, H, W, make_case


def export_case(case: Path, fmt: str, out: Path | None = None, **kw) -> ExportResult:
    """The export with the engine's stage folders, as the command passes them."""
    return export.export_case(case, fmt, out, folders=build_pipeline().folders(case), **kw)


def cameras_of(case: Path) -> CamerasFile:
    return CamerasFile.model_validate_json((case / "02_poses" / "cameras.json").read_text())


def registered(case: Path) -> dict[int, np.ndarray]:
    return {f.index: np.asarray(f.c2w) for f in cameras_of(case).frames if f.registered and f.c2w}


@pytest.fixture
def case(tmp_path: Path) -> Path:
    return make_case(tmp_path)


def test_stage_folders_come_from_the_engine(case: Path) -> None:
    folders = build_pipeline().folders(case)
    assert folders["poses"] == case / "02_poses" and folders["mesh"] == case / "06_mesh"
    (case / "exports").mkdir()
    assert "exports" not in folders.values()
    # a stage folder under another name is not this case's stage: no poses, no export
    (case / "02_poses").rename(case / "02_poses_old")
    with pytest.raises(EndopipeError, match="no camera poses"):
        export_case(case, "colmap")


# --- nerfstudio -----------------------------------------------------------------------------------


@pytest.mark.parametrize("camera_scale", [1, 2])
def test_nerfstudio_round_trip(tmp_path: Path, camera_scale: int) -> None:
    case = make_case(tmp_path, camera_scale=camera_scale)
    result = export_case(case, "nerfstudio")
    out = case / "exports" / "nerfstudio"
    assert result.out == out and result.frames == 5
    pose_set = read_transforms_json(out / "transforms.json")  # the project's one reader
    k, poses = pose_set.camera, pose_set.c2w
    expected_k = cameras_of(case).intrinsics().scaled(W, H)  # scaled to the exported images
    for name in ("width", "height", "fx", "fy", "cx", "cy", "model", "dist"):
        assert getattr(k, name) == pytest.approx(getattr(expected_k, name)), name
    want = registered(case)
    assert sorted(poses) == [f"{i:06d}.png" for i in sorted(want)]
    for i, c2w in want.items():
        assert np.allclose(poses[f"{i:06d}.png"], c2w, atol=1e-9)

    data = json.loads((out / "transforms.json").read_text())
    frame = data["frames"][0]
    gl = np.asarray(frame["transform_matrix"])
    assert np.allclose(gl, want[0] @ OPENGL_FROM_OPENCV)  # y and z camera axes flipped
    assert np.allclose(gl[:3, 2], -want[0][:3, 2])  # OpenGL cameras look down -z
    # images, masks and depth (x 1000 for nerfstudio's default depth_unit_scale_factor)
    assert filecmp.cmp(out / frame["file_path"], case / "01_ingest" / "frames" / "000000.png")
    assert filecmp.cmp(out / frame["mask_path"], case / "01_ingest" / "masks" / "000000.png")
    depth = np.load(out / frame["depth_file_path"])
    assert np.allclose(depth / 1000.0, np.load(case / "05_depth" / "depth" / "000000.npy"))
    meta = json.loads((out / "export.json").read_text())
    assert meta["skipped_unregistered"] == [UNREGISTERED] and meta["units"] == "mm"


def test_nerfstudio_without_depth_and_with_symlinks(tmp_path: Path) -> None:
    case = make_case(tmp_path, stages=("ingest", "poses"))
    result = export_case(case, "nerfstudio", tmp_path / "ns", symlink=True)
    data = json.loads((tmp_path / "ns" / "transforms.json").read_text())
    assert all("depth_file_path" not in f for f in data["frames"])
    assert (tmp_path / "ns" / "images" / "000000.png").is_symlink()
    assert any("no 05_depth" in n for n in result.notes)


# --- colmap ---------------------------------------------------------------------------------------


def test_colmap_written_from_cameras_json(case: Path) -> None:
    export_case(case, "colmap")
    out = case / "exports" / "colmap"
    model = read_colmap_model(out / "sparse" / "0")
    camera, poses = model.camera, model.c2w
    assert model.colmap_model == "PINHOLE" and (camera.width, camera.height) == (W, H)
    k, want_k = camera, cameras_of(case).intrinsics()
    assert (k.fx, k.fy, k.cx, k.cy) == pytest.approx((want_k.fx, want_k.fy, want_k.cx, want_k.cy))
    want = registered(case)
    assert sorted(poses) == [f"{i:06d}.png" for i in sorted(want)]
    for i, c2w in want.items():
        assert np.allclose(poses[f"{i:06d}.png"], c2w, atol=1e-9)
        assert (out / "images" / f"{i:06d}.png").is_file()
    assert "# Number of points: 0" in (out / "sparse" / "0" / "points3D.txt").read_text()


def test_colmap_model_is_read_by_pycolmap(case: Path) -> None:
    export_case(case, "colmap")
    pose_set = read_colmap_model(case / "exports" / "colmap")
    for i, c2w in registered(case).items():
        assert np.allclose(pose_set.c2w[f"{i:06d}.png"], c2w, atol=1e-6)


def test_colmap_copies_the_poses_stage_model(tmp_path: Path) -> None:
    case = make_case(tmp_path, sparse=True)
    result = export_case(case, "colmap")
    out = case / "exports" / "colmap" / "sparse" / "0"
    for name in ("cameras.txt", "images.txt", "points3D.txt"):
        assert filecmp.cmp(out / name, case / "02_poses" / "sparse" / name, shallow=False)
    assert any("copied" in n for n in result.notes)
    poses = read_colmap_model(out).c2w
    for i, c2w in registered(case).items():
        assert np.allclose(poses[f"{i:06d}.png"], c2w, atol=1e-9)


# --- endonerf -------------------------------------------------------------------------------------


@pytest.mark.parametrize("axes", ENDONERF_AXES)
def test_endonerf_round_trip(case: Path, tmp_path: Path, axes: str) -> None:
    out = tmp_path / f"endo_{axes}"
    export_case(case, "endonerf", out, endonerf_axes=axes)
    bounds, poses = read_endonerf(out, axes)
    want = registered(case)
    assert len(poses) == len(want)
    for c2w, (_, expected) in zip(poses, sorted(want.items()), strict=True):
        assert np.allclose(c2w, expected, atol=1e-9)
    arr = np.load(out / "poses_bounds.npy")
    assert arr.shape == (len(want), 17)
    hwf = arr[0, :15].reshape(3, 5)[:, 4]
    assert tuple(hwf) == pytest.approx((H, W, cameras_of(case).fx))
    # near / far: LLFF's 0.1 / 99.9 percentiles of each frame's depth
    first = np.load(case / "05_depth" / "depth" / "000000.npy")
    z = first[first > 0]
    assert bounds[0] == pytest.approx([np.percentile(z, 0.1), np.percentile(z, 99.9)])
    assert np.all(bounds[:, 0] < bounds[:, 1])
    # files: sorted names pair up; masks in EndoNeRF's meaning (255 = exclude); 16-bit depth
    names = sorted(p.name for p in (out / "images").iterdir())
    assert names[0] == "frame-000000.color.png" and len(names) == len(want)
    assert len(list((out / "depth").iterdir())) == len(list((out / "masks").iterdir())) == len(want)
    mask = cv2.imread(str(out / "masks" / "frame-000000.mask.png"), cv2.IMREAD_GRAYSCALE)
    ours = cv2.imread(str(case / "01_ingest" / "masks" / "000000.png"), cv2.IMREAD_GRAYSCALE)
    assert np.array_equal(mask == 255, ours == 0)
    png = cv2.imread(str(out / "depth" / "frame-000000.depth.png"), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint16
    meta = json.loads((out / "endonerf.json").read_text())
    assert meta["depth_scale"] == 100.0
    assert np.allclose(png / meta["depth_scale"], first, atol=0.006)


def test_endonerf_llff_matches_the_llff_loader_convention(case: Path, tmp_path: Path) -> None:
    """What NeRF's load_llff does with a row (swap to right, up, back) gives OpenGL's c2w."""
    export_case(case, "endonerf", tmp_path / "e", endonerf_axes="llff")
    arr = np.load(tmp_path / "e" / "poses_bounds.npy")
    poses = arr[:, :15].reshape(-1, 3, 5).transpose(1, 2, 0)  # as load_llff reads it
    poses = np.concatenate([poses[:, 1:2], -poses[:, 0:1], poses[:, 2:]], 1)  # its column swap
    for n, (_, c2w) in enumerate(sorted(registered(case).items())):
        gl = c2w @ OPENGL_FROM_OPENCV
        assert np.allclose(poses[:, :4, n], gl[:3, :4], atol=1e-9)


def test_llff_matrix_inverse_and_depth_scale() -> None:
    c2w = np.eye(4)
    c2w[:3, :3] = cv2.Rodrigues(np.array([0.3, -0.2, 0.5]))[0]
    c2w[:3, 3] = [1, 2, 3]
    for axes in ENDONERF_AXES:
        m = llff_matrix(c2w, (48, 64, 50), axes)
        assert np.allclose(c2w_from_llff(m, axes), c2w)
    m = llff_matrix(c2w, (48, 64, 50), "llff")
    assert np.allclose(m[:, 0], c2w[:3, 1]) and np.allclose(m[:, 2], -c2w[:3, 2])  # down, back
    assert endonerf_depth_scale(120.0) == 100.0
    assert endonerf_depth_scale(5000.0) == pytest.approx(10.0)
    assert 6000.0 * endonerf_depth_scale(6000.0) <= 65535


def test_endonerf_bounds_without_depth(tmp_path: Path) -> None:
    case = make_case(tmp_path, stages=("ingest", "poses", "centerline"))
    result = export_case(case, "endonerf")
    bounds, _ = read_endonerf(case / "exports" / "endonerf")
    assert np.allclose(bounds, [[0.3, 36.0]] * 5)  # from the centre line's radius (6 mm)
    assert not (case / "exports" / "endonerf" / "depth").exists()
    assert any("centre line radius" in n for n in result.notes)


# --- ply ------------------------------------------------------------------------------------------


def test_ply_round_trip(case: Path) -> None:
    result = export_case(case, "ply")
    out = case / "exports" / "ply"
    assert set(result.files) == {"mesh.ply", "points.ply", "cameras.ply"}
    cams = trimesh.load(out / "cameras.ply", process=False)
    want = registered(case)
    centres = np.array([want[i][:3, 3] for i in sorted(want)])
    assert np.allclose(cams.vertices, centres, atol=1e-5)
    # fused points lie on the wall the depth maps see, i.e. the poses were applied right
    cloud = trimesh.load(out / "points.ply", process=False)
    assert len(cloud.vertices) > 100
    assert np.allclose(cloud.vertices[:, 2], WALL_Z, atol=1e-3)
    assert filecmp.cmp(out / "mesh.ply", case / "06_mesh" / "mesh.ply", shallow=False)


def test_ply_points_are_voxel_thinned_to_max_points(case: Path, tmp_path: Path) -> None:
    full = export_case(case, "ply", tmp_path / "full", point_stride=1)
    thin = export_case(case, "ply", tmp_path / "thin", point_stride=1, max_points=300)
    n_full = len(trimesh.load(tmp_path / "full" / "points.ply", process=False).vertices)
    cloud = trimesh.load(tmp_path / "thin" / "points.ply", process=False)
    assert n_full > 1000 and 100 < len(cloud.vertices) <= 300
    assert f"{len(cloud.vertices):,} points" in " ".join(thin.notes)
    assert np.allclose(cloud.vertices[:, 2], WALL_Z, atol=1e-3)  # still on the wall
    # the thinned cloud still covers what the full one covers (the voxels are < 1/10 of it)
    full_pts = trimesh.load(tmp_path / "full" / "points.ply", process=False).vertices
    span = np.ptp(full_pts[:, :2], axis=0)
    assert np.all(np.ptp(cloud.vertices[:, :2], axis=0) > 0.9 * span)
    colours = np.asarray(cloud.visual.vertex_colors)[:, :3]
    assert colours.std() > 0 and len(full.notes) == len(thin.notes)


def test_ply_needs_a_mesh_or_depth(tmp_path: Path) -> None:
    case = make_case(tmp_path, stages=("ingest", "poses"))
    with pytest.raises(EndopipeError, match="nothing to export"):
        export_case(case, "ply")
    assert not (case / "exports" / "ply").exists()


# --- errors and the command -----------------------------------------------------------------------


def test_export_errors(tmp_path: Path) -> None:
    case = make_case(tmp_path, stages=("ingest",))
    with pytest.raises(EndopipeError, match="no camera poses"):
        export_case(case, "colmap")
    case2 = make_case(tmp_path / "b")
    with pytest.raises(EndopipeError, match="unknown export format"):
        export_case(case2, "obj")
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "keep.txt").write_text("user data")
    with pytest.raises(EndopipeError, match="not an endopipe export"):
        export_case(case2, "colmap", foreign)
    assert (foreign / "keep.txt").read_text() == "user data"
    export_case(case2, "colmap", tmp_path / "again")
    export_case(case2, "colmap", tmp_path / "again")  # an earlier export is replaced


def test_export_command(case: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "ns"
    assert main(["export", str(case), "--format", "nerfstudio", "--out", str(out)]) == 0
    assert (out / "transforms.json").is_file()
    assert "exported 5 frame(s) as nerfstudio" in capsys.readouterr().out
    assert main(["export", str(case), "--format", "obj"]) == 2
    assert main(["export", str(tmp_path / "nowhere"), "--format", "ply"]) == 2
