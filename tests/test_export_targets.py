"""`endopipe export --format endonerf --for T` read as each tool's loader reads it.

Each test re-implements the few lines of the target's public loader that turn poses_bounds.npy,
depth/ and masks/ into points (its axes, its units, its image size, its back-projection; the file
is cited above each), and checks that every frame's points land on the scene's one surface: the
synthetic case's exact mesh, within 1% of the scene's size. The case is a synthetic colon with a
moving camera (2 mm a frame: where depth and translations in two units scatter the frames), posed
by its exact poses, its 05_depth the exact depth at the working size.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh
from PIL import Image
from scipy.spatial import cKDTree

from endopipe import export
from endopipe.cli import build_pipeline, main
from endopipe.pipeline.cache import Manifest, list_files
from endopipe.pipeline.errors import EndopipeError
from endopipe.stages.depth.summary import DepthSummary
from endopipe.stages.ingest.view import IngestView

SOURCE = (480, 384)  # the synthetic input's size; the working frames are 320 x 256
#: The share of a frame's points that may miss: EndoGaussian clips each frame's nearest 3% of
#: depths up to its 3rd percentile (its own loader's rule), and depth edges mix at resampling.
OUTLIERS = 0.05
TOLERANCE = 0.01  # of the scene's size


# --- the case -------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def case(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A synthetic colon (5 frames, 480 x 384, 2 mm a frame) through ingest and poses (its exact
    poses), and a 05_depth of its exact depth at the working size (about 30 s, once)."""
    from endopipe.synth import SynthConfig, generate_case

    src = tmp_path_factory.mktemp("targets") / "colon"
    generate_case(src, SynthConfig(seed=3, frames=5, width=SOURCE[0], height=SOURCE[1], step_mm=2))
    wd = src.parent / "wd"
    run = ["run", str(src / "video.mp4"), "--workdir", str(wd), "--until", "poses", "--quiet"]
    assert main([*run, "--set", "poses.source=gt"]) == 0
    case = wd / "colon"
    write_exact_depth(case, src / "gt")
    return case


def write_exact_depth(case: Path, gt: Path) -> None:
    """05_depth as the depth stage would leave it, from the exact depth (bilinear to the
    working size: the depth at each working pixel's centre)."""
    ingest = IngestView(case / "01_ingest")
    out = case / "05_depth"
    (out / "depth").mkdir(parents=True)
    for f in ingest.frames:
        exact = np.load(gt / "depth" / f"{f.source_index:06d}.npy")
        d = cv2.resize(exact, (ingest.width, ingest.height), interpolation=cv2.INTER_LINEAR)
        np.save(out / "depth" / f"{f.index:06d}.npy", d.astype(np.float32))
    summary = DepthSummary(
        frames=len(ingest.frames),
        units="mm",
        png_scale=1000.0,
        ms_per_frame=0.0,
        bake_s=0.0,
        renderer="exact",
    )
    now = time.time()
    manifest = Manifest(
        stage="depth",
        key="exact",
        version=1,
        config={},
        upstream={},
        started=now,
        finished=now,
        wall_s=0.0,
        peak_rss_mb=0.0,
        summary=summary.model_dump(mode="json"),
        files=list_files(out),
    )
    (out / "manifest.json").write_text(manifest.model_dump_json())


@pytest.fixture(scope="module")
def surface(case: Path) -> cKDTree:
    """The exact mesh's vertices (about 0.2 mm apart), in mm."""
    gt = Path(json.loads((case / "case.json").read_text())["gt_dir"])
    mesh = trimesh.load(gt / "mesh.ply", process=False)
    return cKDTree(np.asarray(mesh.vertices))


def exported(case: Path, tmp_path: Path, target: str, resolution: str = "working") -> Path:
    out = tmp_path / target
    export.export_case(
        case,
        "endonerf",
        out,
        folders=build_pipeline().folders(case),
        target=target,
        resolution=resolution,
    )
    return out


def on_one_surface(points: list[np.ndarray], tree: cKDTree, scale: float) -> None:
    """Every frame's points (in the export's units, `scale` per mm) lie on the exact surface
    within TOLERANCE of the scene's size (the diagonal of what the frames see), but for
    OUTLIERS of them."""
    allpts = np.concatenate(points) / scale
    lo, hi = np.percentile(allpts, [1, 99], axis=0)
    size = float(np.linalg.norm(hi - lo))
    assert size > 20.0  # a colon seen down its length (mm): the frames' points were not lost
    for n, pts in enumerate(points):
        assert len(pts) > 1000, f"frame {n}: {len(pts)} points"
        dist, _ = tree.query(pts[:: max(1, len(pts) // 4000)] / scale)
        share = float(np.mean(dist > TOLERANCE * size))
        assert share <= OUTLIERS, (
            f"frame {n}: {share:.1%} of its points farther than {TOLERANCE * size:.2f} mm from "
            f"the surface (median {np.median(dist):.2f} mm)"
        )


def frames_of(out: Path, kind: str) -> list[Path]:
    return sorted((out / kind).glob("*.png"))


# --- the loaders ----------------------------------------------------------------------------------


def endonerf_points(out: Path) -> list[np.ndarray]:
    """med-air/EndoNeRF, load_llff.py `_load_data` / `load_llff_data(davinci_endoscopic=True)`
    (configs/*.txt): the 3x5 kept as it is (no column swap), hwf's h, w replaced by the image's
    shape, f as it is; run_endonerf_helpers.py `get_rays`: dirs ((i - W*.5)/f, -(j - H*.5)/f,
    -1) rotated by c2w[:3, :3], origin c2w[:3, -1]; depth imageio-read as it is, the mean
    distance along rays_d with no_ndc; masks 1 - mask / 255 (255 = tool)."""
    poses_arr = np.load(out / "poses_bounds.npy")
    poses = poses_arr[:, :-2].reshape([-1, 3, 5])
    points = []
    for n, (img, dep, msk) in enumerate(
        zip(frames_of(out, "images"), frames_of(out, "depth"), frames_of(out, "masks"), strict=True)
    ):
        H, W = np.array(Image.open(img)).shape[:2]  # poses[:2, 4, :] = sh[:2]
        focal = poses[n, 2, 4]
        c2w = poses[n, :3, :4]
        i, j = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
        dirs = np.stack([(i - W * 0.5) / focal, -(j - H * 0.5) / focal, -np.ones_like(i)], -1)
        rays_d = np.sum(dirs[..., np.newaxis, :] * c2w[:3, :3], -1)
        rays_o = np.broadcast_to(c2w[:3, -1], np.shape(rays_d))
        depth = np.asarray(Image.open(dep)).astype(np.float64)
        keep = (1.0 - np.asarray(Image.open(msk)) / 255.0 > 0.5) & (depth > 0)
        points.append((rays_o + rays_d * depth[..., None])[keep])
    return points


def endogaussian_points(out: Path) -> list[np.ndarray]:
    """CUHK-AIM-Group/EndoGaussian, scene/endo_loader.py `EndoNeRF_Dataset` (downsample=1.0, as
    scene/dataset_readers.py `readEndoNeRFInfo` passes it): img_wh (640, 512); focal hwf's f;
    poses[..., :4] taken as they are as the c2w (the OpenGL flip commented out);
    `get_color_depth_mask`: depth = np.array(Image.open(png)) clipped to its 3rd..99.8th
    percentile of non-zero values, mask = 1 - mask / 255; `get_pts_cam`:
    X = (i - W/2) / f * Z, Y = (j - H/2) / f * Z over the mask; `get_pts_wld`: c2w @ X."""
    poses_arr = np.load(out / "poses_bounds.npy")
    poses = poses_arr[:, :-2].reshape([-1, 3, 5])
    focal = poses[0, 2, 4]
    W, H = 640, 512
    points = []
    for n, (img, dep, msk) in enumerate(
        zip(frames_of(out, "images"), frames_of(out, "depth"), frames_of(out, "masks"), strict=True)
    ):
        c2w = np.concatenate((poses[n, :, :4], np.array([[0, 0, 0, 1]])), axis=0)
        depth = np.array(Image.open(dep)).astype(np.float64)
        close_depth = np.percentile(depth[depth != 0], 3.0)
        inf_depth = np.percentile(depth[depth != 0], 99.8)
        depth = np.clip(depth, close_depth, inf_depth)
        mask = 1 - np.array(Image.open(msk)) / 255.0
        color = np.array(Image.open(img)) / 255.0
        i, j = np.meshgrid(np.linspace(0, W - 1, W), np.linspace(0, H - 1, H))
        X_Z, Y_Z = (i - W / 2) / focal, (j - H / 2) / focal
        pts = np.stack((X_Z * depth, Y_Z * depth, depth), axis=-1).reshape(-1, 3)
        assert color.reshape(-1, 3).shape[0] == pts.shape[0]  # the image is 640 x 512
        pts = pts[mask.reshape(-1).astype(bool)]
        homo = np.concatenate((pts, np.ones((pts.shape[0], 1))), axis=-1)
        points.append((c2w @ homo.T).T[:, :3])
    return points


def deform3dgs_points(out: Path) -> list[np.ndarray]:
    """jinlab-imvr/Deform3DGS, scene/endo_loader.py `EndoNeRF_Dataset` (a path without
    'stereo_'): poses with columns 1 and 2 negated; K = [[f, 0, W//2], [0, f, H//2]] from hwf;
    img_wh (640, 512); `search_pts_colors_with_motion`: depth raw, dropped outside its 3rd..99.8th
    percentile and where 0, mask = 1 - mask / 255; `get_pts_cam` with K; to the world by the
    frame's c2w (`get_camera_poses` of its (R, T), i.e. the c2w)."""
    poses_arr = np.load(out / "poses_bounds.npy")
    poses = poses_arr[:, :-2].reshape([-1, 3, 5])
    H, W, focal = poses[0, :, -1]
    K = np.array([[focal, 0, W // 2], [0, focal, H // 2], [0, 0, 1]])
    poses = np.concatenate(
        [poses[..., :1], -poses[..., 1:2], -poses[..., 2:3], poses[..., 3:4]], -1
    )
    w, h = 640, 512
    points = []
    for n, (dep, msk) in enumerate(
        zip(frames_of(out, "depth"), frames_of(out, "masks"), strict=True)
    ):
        c2w = np.concatenate((poses[n], np.array([[0, 0, 0, 1]])), axis=0)
        depth = np.array(Image.open(dep)).astype(np.float64)
        mask = 1 - np.array(Image.open(msk)) / 255.0
        depth_mask = np.ones(depth.shape)
        close_depth = np.percentile(depth[depth != 0], 3.0)
        inf_depth = np.percentile(depth[depth != 0], 99.8)
        depth_mask[depth > inf_depth] = 0
        depth_mask[np.bitwise_and(depth < close_depth, depth != 0)] = 0
        depth_mask[depth == 0] = 0
        mask = np.logical_and(depth_mask, mask)
        i, j = np.meshgrid(np.linspace(0, w - 1, w), np.linspace(0, h - 1, h))
        X_Z, Y_Z = (i - K[0, -1]) / focal, (j - K[1, -1]) / focal
        pts = np.stack((X_Z * depth, Y_Z * depth, depth), axis=-1).reshape(-1, 3)
        pts = pts[mask.reshape(-1)]
        homo = np.concatenate((pts, np.ones((pts.shape[0], 1))), axis=-1)
        points.append((c2w @ homo.T).T[:, :3])
    return points


def pose_scale(out: Path) -> float:
    """Translations per mm, as the export says (the test's surface is in mm)."""
    return float(json.loads((out / "endonerf.json").read_text())["pose_scale"])


# --- the tests ------------------------------------------------------------------------------------


def test_endonerf_loader_puts_every_frame_on_the_surface(case, surface, tmp_path) -> None:
    out = exported(case, tmp_path, "endonerf")
    assert np.array(Image.open(frames_of(out, "images")[0])).shape[:2] == (256, 320)
    on_one_surface(endonerf_points(out), surface, pose_scale(out))


def test_endogaussian_loader_puts_every_frame_on_the_surface(case, surface, tmp_path) -> None:
    out = exported(case, tmp_path, "endogaussian")
    assert np.array(Image.open(frames_of(out, "images")[0])).shape[:2] == (512, 640)
    on_one_surface(endogaussian_points(out), surface, pose_scale(out))


def test_deform3dgs_loader_puts_every_frame_on_the_surface(case, surface, tmp_path) -> None:
    out = exported(case, tmp_path, "deform3dgs")
    assert np.array(Image.open(frames_of(out, "images")[0])).shape[:2] == (512, 640)
    on_one_surface(deform3dgs_points(out), surface, pose_scale(out))


def test_source_resolution_with_upsampled_depth(case, surface, tmp_path) -> None:
    """--resolution source: the input's 480 x 384 frames, the depth upsampled from 320 x 256,
    then to EndoGaussian's 640 x 512; still one surface, and the notes say how."""
    out = exported(case, tmp_path, "endogaussian", resolution="source")
    meta = json.loads((out / "endonerf.json").read_text())
    assert meta["resolution"] == "source" and any("joint" in n for n in meta["notes"])
    on_one_surface(endogaussian_points(out), surface, pose_scale(out))
    # the source's own pixels: sharper than the working frames brought to the same size
    work = exported(case, tmp_path / "w", "endogaussian")
    grads = [
        cv2.Laplacian(
            cv2.imread(str(frames_of(o, "images")[1]), cv2.IMREAD_GRAYSCALE), cv2.CV_64F
        ).var()
        for o in (out, work)
    ]
    assert grads[0] > 1.2 * grads[1]


def test_the_check_fails_on_the_old_layout(case, surface, tmp_path) -> None:
    """The checks can fail: the layout without a target (the working size, depth x 100,
    translations in mm) cannot even be read by EndoGaussian's loader; at its size but with those
    units a moving camera's frames scatter; and another loader's axes miss the surface."""
    old = tmp_path / "old"
    export.export_case(
        case, "endonerf", old, folders=build_pipeline().folders(case), endonerf_axes="opencv"
    )
    with pytest.raises(ValueError, match="broadcast"):  # 320 x 256 depth on its 640 x 512 grid
        endogaussian_points(old)
    out = exported(case, tmp_path, "endogaussian")
    scale = pose_scale(out)
    assert scale == 100.0  # 0.01 mm: the PNG's counts, and the translations' unit
    arr = np.load(out / "poses_bounds.npy")
    rows = arr[:, :15].reshape(-1, 3, 5)
    rows[:, :, 3] /= scale  # translations back in mm, depth still x 100
    arr[:, :15] = rows.reshape(-1, 15)
    np.save(out / "poses_bounds.npy", arr)
    with pytest.raises(AssertionError, match="farther than"):
        on_one_surface(endogaussian_points(out), surface, scale)
    with pytest.raises(AssertionError, match="farther than"):  # OpenGL axes read from OpenCV's
        on_one_surface(
            deform3dgs_points(exported(case, tmp_path / "x", "endogaussian")), surface, scale
        )


def test_for_and_axes_are_one_choice(case, tmp_path) -> None:
    folders = build_pipeline().folders(case)
    with pytest.raises(EndopipeError, match="drop --endonerf-axes"):
        export.export_case(
            case,
            "endonerf",
            tmp_path / "a",
            folders=folders,
            target="endogaussian",
            endonerf_axes="llff",
        )
    with pytest.raises(EndopipeError, match="unknown --for"):
        export.export_case(case, "endonerf", tmp_path / "b", folders=folders, target="gs")
    with pytest.raises(EndopipeError, match="endonerf only"):
        export.export_case(case, "colmap", tmp_path / "c", folders=folders, target="endonerf")
    with pytest.raises(EndopipeError, match="resolution source writes"):
        export.export_case(case, "colmap", tmp_path / "d", folders=folders, resolution="source")
    assert not any(p.name.startswith(("a", "b", "c", "d")) for p in tmp_path.iterdir())


def test_nerfstudio_depth_pngs_for_readers_without_npy(case, surface, tmp_path) -> None:
    """nerfstudio-project/nerfstudio, nerfstudio/data/utils/data_utils.py
    `get_depth_image_from_path` before its .npy support: cv2.imread(IMREAD_ANYDEPTH) x 1e-3
    (the default depth_unit_scale_factor) x the dataparser's scale (1 here); transforms.json's
    OpenGL c2w, fl_x / cx in its pixel-edge convention: the PNGs land on the surface."""
    out = tmp_path / "ns"
    export.export_case(case, "nerfstudio", out, folders=build_pipeline().folders(case))
    meta = json.loads((out / "transforms_png.json").read_text())
    factor = meta["endopipe"]["depth_unit_scale_factor"]
    # the colon's deepest (about 225 mm) does not fit in um counts: 0.01 mm, factor 0.01, said
    assert factor == pytest.approx(1e-2)
    points = []
    for fr in meta["frames"]:
        depth = cv2.imread(str(out / fr["depth_file_path"]), cv2.IMREAD_ANYDEPTH) * factor
        npy = out / "depth" / Path(fr["depth_file_path"]).with_suffix(".npy").name
        assert np.allclose(depth, np.load(npy) * 1e-3, atol=factor)  # the .npy's depth
        h, w = depth.shape
        u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)  # pixel edges: centres +0.5
        x, y = (u - meta["cx"]) / meta["fl_x"], (v - meta["cy"]) / meta["fl_y"]
        cam = np.stack([x * depth, -y * depth, -depth], -1)[depth > 0]  # OpenGL: y up, z back
        c2w = np.asarray(fr["transform_matrix"])
        points.append(cam @ c2w[:3, :3].T + c2w[:3, 3])
    on_one_surface(points, surface, 1.0)


def test_reframe_centres_the_principal_point_or_refuses() -> None:
    from endopipe.export.reframe import reframe
    from endopipe.pipeline.errors import InputError
    from endopipe.stages.camera import Camera

    k = Camera(width=64, height=48, fx=50.0, fy=52.0, cx=31.0, cy=24.5)
    r = reframe(k, (640, 512), (319.5, 255.5))
    assert r.camera.fx == r.camera.fy and (r.camera.cx, r.camera.cy) == (319.5, 255.5)
    # the frame's principal point lands on the target's, and every target pixel is inside it
    assert r.sx * k.cx + r.tx == pytest.approx(319.5) and r.sy * k.cy + r.ty == pytest.approx(255.5)
    assert (0.5 - 0.5 - r.tx) / r.sx >= -0.5 - 1e-9 and (639 + 0.5 - r.tx) / r.sx <= 63.5 + 1e-9
    with pytest.raises(InputError, match="keeps"):
        reframe(k.model_copy(update={"cx": 4.0}), (640, 512))


def test_export_command_for_a_target(case, tmp_path, capsys) -> None:
    out = tmp_path / "cli"
    assert (
        main(
            ["export", str(case), "--format", "endonerf", "--for", "deform3dgs", "--out", str(out)]
        )
        == 0
    )
    said = capsys.readouterr().out
    assert "for deform3dgs" in said and "stereo_" in said
    assert json.loads((out / "export.json").read_text())["for"] == "deform3dgs"
    assert main(["export", str(case), "--format", "endonerf", "--for", "gs"]) == 2
