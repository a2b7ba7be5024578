"""`endopipe synth`: the case folder of docs/formats.md, its ground truth exact and consistent.

Depth, poses and mesh are checked against each other (not against the generator's own numbers),
hits against a brute-force march, the fast mesh-guided tracer against the reference one.
"""

from __future__ import annotations

import json
from pathlib import Path

import av
import cv2
import numpy as np
import open3d as o3d
import pytest
from pydantic import ValidationError
from scipy.ndimage import map_coordinates

from endopipe.stages.camera import Camera, backproject, project
from endopipe.synth import SynthConfig, SynthSummary, generate_case
from endopipe.synth.generate import Setup, prepare
from endopipe.synth.raycast import MeshGuide, camera_rays, trace_frame

SMALL = {"frames": 12, "width": 160, "height": 128}
SHAPES = ("colon", "cavity")


@pytest.fixture(scope="module")
def cases(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, SynthSummary]]:
    root = tmp_path_factory.mktemp("synth")
    return {
        shape: (root / shape, generate_case(root / shape, SynthConfig(shape=shape, **SMALL)))
        for shape in SHAPES
    }


@pytest.fixture(scope="module")
def colon_setup() -> Setup:
    return prepare(SynthConfig(shape="colon", **SMALL))


def load(case: Path) -> tuple[Camera, np.ndarray, list[np.ndarray]]:
    intr = Camera.load(case / "intrinsics.json")
    poses = np.array(json.loads((case / "gt" / "poses.json").read_text())["poses"])
    depths = [np.load(p) for p in sorted((case / "gt" / "depth").glob("*.npy"))]
    return intr, poses, depths


@pytest.mark.parametrize("shape", SHAPES)
def test_case_folder_has_every_file(cases: dict, shape: str) -> None:
    case, summary = cases[shape]
    n = SMALL["frames"]
    intr, poses, depths = load(case)
    assert (intr.width, intr.height) == (SMALL["width"], SMALL["height"])
    assert intr.fx == pytest.approx(SMALL["width"] / 2)  # 90 deg horizontal field of view
    meta = json.loads((case / "gt" / "poses.json").read_text())
    assert (meta["convention"], meta["units"]) == ("opencv_c2w", "mm")
    assert poses.shape == (n, 4, 4)
    assert np.allclose(poses[:, :3, :3] @ poses[:, :3, :3].transpose(0, 2, 1), np.eye(3), atol=1e-9)
    assert len(depths) == n and all(d.dtype == np.float32 for d in depths)
    assert all(d.shape == (intr.height, intr.width) for d in depths)
    assert np.mean([(d > 0).mean() for d in depths]) > 0.99  # misses are rare
    assert len(list((case / "frames").glob("*.png"))) == n
    assert len(list((case / "gt" / "specular").glob("*.png"))) == n
    cl = json.loads((case / "gt" / "centerline.json").read_text())
    assert len(cl["points"]) == len(cl["radius"]) > 10
    assert summary.frames == n
    assert 0.7 * (n - 1) < summary.path_length_mm < 1.3 * (n - 1)  # ~1 mm per frame
    low, high = (12.0, 20.0) if shape == "colon" else (25.0, 60.0)
    assert low < summary.mean_radius_mm < high
    assert summary.mean_radius_mm == pytest.approx(np.mean(cl["radius"]))


@pytest.mark.parametrize("shape", SHAPES)
def test_depth_reprojects_into_the_next_frame(cases: dict, shape: str) -> None:
    """Frame i's depth, moved with the GT poses, is frame i+1's depth where both see it."""
    intr, poses, depths = load(cases[shape][0])
    errors, compared = [], 0
    for i in range(len(depths) - 1):
        valid = depths[i] > 0
        pts = backproject(intr, depths[i].astype(np.float64), poses[i])[valid]
        uv, z = project(intr, pts, poses[i + 1])
        inside = (
            (z > 0)
            & (uv[:, 0] >= 0)
            & (uv[:, 0] <= intr.width - 1)
            & (uv[:, 1] >= 0)
            & (uv[:, 1] <= intr.height - 1)
        )
        uv, z = uv[inside], z[inside]
        nxt = depths[i + 1].astype(np.float64)
        sampled = map_coordinates(nxt, [uv[:, 1], uv[:, 0]], order=1)
        all_valid = map_coordinates((nxt > 0).astype(float), [uv[:, 1], uv[:, 0]], order=1) == 1
        errors.append(np.abs(sampled - z)[all_valid] / z[all_valid])
        compared += int(all_valid.sum())
    errors = np.concatenate(errors)
    assert compared > 0.5 * (len(depths) - 1) * intr.width * intr.height
    assert np.median(errors) < 0.005
    assert np.median(errors) < 1e-3  # in fact far below the bound: exact GT, bilinear sampling


@pytest.mark.parametrize("shape", SHAPES)
def test_mesh_lies_on_the_backprojected_depth(cases: dict, shape: str) -> None:
    case, summary = cases[shape]
    intr, poses, depths = load(case)
    pts = np.concatenate(
        [
            backproject(intr, depths[i].astype(np.float64), poses[i])[depths[i] > 0]
            for i in (0, 6, 11)
        ]
    )
    pts = pts[:: max(1, len(pts) // 30000)]
    mesh = o3d.t.io.read_triangle_mesh(str(case / "gt" / "mesh.ply"))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    dist = scene.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy()
    assert np.median(dist) < 0.002 * summary.mean_radius_mm
    assert np.percentile(dist, 99) < 0.01 * summary.mean_radius_mm


@pytest.mark.parametrize("shape", SHAPES)
def test_video_frame_i_is_png_frame_i(cases: dict, shape: str) -> None:
    case, _ = cases[shape]
    pngs = [cv2.imread(str(p))[:, :, ::-1] for p in sorted((case / "frames").glob("*.png"))]
    with av.open(str(case / "video.mp4")) as container:
        decoded = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    assert len(decoded) == SMALL["frames"]
    assert decoded[0].shape == (SMALL["height"], SMALL["width"], 3)
    for i, frame in enumerate(decoded):
        diff = [np.abs(frame.astype(float) - p).mean() for p in pngs]
        assert int(np.argmin(diff)) == i
        assert diff[i] < 4.0  # high-quality H.264 of the same image


@pytest.mark.parametrize("shape", SHAPES)
def test_specular_mask_is_a_few_percent(cases: dict, shape: str) -> None:
    case, _ = cases[shape]
    masks = [
        cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        for p in sorted((case / "gt" / "specular").glob("*.png"))
    ]
    assert set(np.unique(np.stack(masks))) <= {0, 255}
    fraction = np.mean([(m == 255).mean() for m in masks])
    assert 0.001 < fraction < 0.10
    # The mask marks highlights: those pixels are among the brightest of their frame.
    frame = cv2.imread(str(sorted((case / "frames").glob("*.png"))[0]), cv2.IMREAD_GRAYSCALE)
    if (masks[0] == 255).any():
        assert np.median(frame[masks[0] == 255]) > np.percentile(frame, 90)


def test_same_seed_same_bytes_other_seed_other_case(tmp_path: Path) -> None:
    cfg = SynthConfig(frames=3, width=64, height=48)
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    generate_case(a, cfg)
    generate_case(b, cfg)
    generate_case(c, cfg.model_copy(update={"seed": 1}))
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for rel in files:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    for rel in ("gt/poses.json", "gt/depth/000000.npy", "frames/000000.png", "gt/mesh.ply"):
        assert (a / rel).read_bytes() != (c / rel).read_bytes(), rel


def test_hits_are_the_first_wall_crossings(colon_setup: Setup) -> None:
    """A brute-force march (0.02 mm steps) finds no wall before any reported hit, and the hit
    itself is on the wall (f = 0 to 1e-6)."""
    setup, frame = colon_setup, 7
    geom = setup.trace(frame)
    assert np.abs(setup.scene.f_points(geom.points)).max() < 1e-6
    origin, dirs, z_per_t = camera_rays(setup.intr, setup.poses[frame])
    t_hit = geom.depth.ravel() / z_per_t
    rng = np.random.default_rng(0)
    pick = rng.choice(np.flatnonzero((t_hit > 0) & (t_hit < 40.0)), 300, replace=False)
    d, t_hit = dirs[pick], t_hit[pick]
    first = np.full(len(pick), np.inf)
    for t in np.arange(0.0, t_hit.max() + 0.5, 0.02):
        inside_wall = setup.scene.f_points(origin + t * d) >= 0
        first = np.where(inside_wall & np.isinf(first), t, first)
    # The march's first wall sample lies within one step after the exact hit.
    lag = first - t_hit
    assert np.mean((lag >= -1e-6) & (lag <= 0.02 + 1e-6)) > 0.99


def test_mesh_guided_tracing_equals_sphere_tracing(colon_setup: Setup) -> None:
    setup, frame = colon_setup, 5
    guide = MeshGuide(setup.scene, *setup.scene.mesh())
    assert guide.error < 0.02  # mm: the mesh is fine enough for gt/mesh.ply too
    fast = trace_frame(setup.scene, setup.bound, guide, setup.intr, setup.poses[frame])
    ref = trace_frame(setup.scene, setup.bound, None, setup.intr, setup.poses[frame])
    assert np.array_equal(fast.valid, ref.valid)
    assert np.mean(np.abs(fast.depth - ref.depth) < 1e-5) > 0.999


def test_config_is_strict(tmp_path: Path) -> None:
    with pytest.raises(ValidationError):
        SynthConfig(width=161)  # H.264 yuv420p needs even sizes
    with pytest.raises(ValidationError):
        SynthConfig(colour="red")
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("not a synth case")
    with pytest.raises(FileExistsError):
        generate_case(foreign, SynthConfig(frames=2, width=32, height=32))
    assert (foreign / "notes.txt").exists()
