"""poses: COLMAP SfM on synthetic and real endoscopy, ground-truth and file sources, quality gate.

Fast tests run on a 20-frame 320x256 synthetic colon; the 60-frame colon, C3VD and the
laparoscopy video are @slow (run with `pytest -m slow tests/test_poses.py`).
"""

from __future__ import annotations

import json
import shutil
from contextlib import nullcontext
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from endopipe.cli import main
from endopipe.pipeline.errors import StageFailed
from endopipe.stages.camera import (
    Camera,
    rotation_angle_deg,
)
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.colmap_model import (
    keep_images,
    read_colmap_model,
)
from endopipe.stages.io.transforms_json import read_transforms_json
from endopipe.stages.poses.config import PosesConfig
from endopipe.stages.poses.view import CamerasFile, PosesView

# ---------------------------------------------------------------- helpers and fixtures


def run(
    capsys: pytest.CaptureFixture | None, source: Path, workdir: Path, *sets: str
) -> tuple[int, str]:
    """`endopipe run SOURCE --workdir WORKDIR --until poses --quiet --set ...`."""
    args = ["run", str(source), "--workdir", str(workdir), "--until", "poses", "--quiet"]
    code = main(args + [a for s in sets for a in ("--set", s)])
    if capsys is None:
        return code, ""
    captured = capsys.readouterr()
    return code, captured.err + captured.out


def summary(case: Path) -> dict:
    return json.loads((case / "02_poses" / "manifest.json").read_text())["summary"]


def gt_poses(case_src: Path) -> list[np.ndarray]:
    data = json.loads((case_src / "gt" / "poses.json").read_text())
    return [np.array(p) for p in data["poses"]]


def assert_one_line_failure(code: int, output: str, expect: str) -> None:
    assert code != 0
    assert "Traceback" not in output, output
    lines = [line for line in output.strip().splitlines() if line.strip()]
    assert lines and "error" in lines[-1].lower(), output
    assert expect in " ".join(lines), output


@pytest.fixture(scope="module")
def colon(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from endopipe.synth import SynthConfig, generate_case

    out = tmp_path_factory.mktemp("synth") / "colon"
    generate_case(out, SynthConfig(seed=0, frames=20, width=320, height=256))
    return out


@pytest.fixture(scope="module")
def colon_rerun(colon: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A second run of the same case (keeping COLMAP's database, which must not change poses)."""
    wd = tmp_path_factory.mktemp("wd")
    code, _ = run(None, colon, wd, "poses.keep_database=true")
    assert code == 0
    return wd / "colon"


@pytest.fixture(scope="module")
def colon_run(colon: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    wd = tmp_path_factory.mktemp("wd")
    code, _ = run(None, colon, wd)
    assert code == 0
    return wd / "colon"


# ---------------------------------------------------------------- COLMAP on a synthetic colon


def test_synthetic_colon_registers_with_small_ate(colon_run: Path) -> None:
    s = summary(colon_run)
    assert s["registered_fraction"] >= 0.9, s
    assert s["ate_percent_of_path"] <= 1.0, s
    assert s["metric"] and s["aligned_to_gt"] and s["intrinsics"] == "fixed"
    assert s["mean_reprojection_px"] < 2.0 and s["mean_track_length"] > 2
    for key in ("models", "mean_points_per_frame", "rre_deg", "ate_mm", "seconds"):
        assert key in s


def test_the_summary_says_how_much_of_the_field_of_view_the_lens_reaches(colon_run: Path) -> None:
    """The synthetic colon's pinhole reaches every pixel; a SIMPLE_RADIAL lens with C3VD's
    k1 = -0.12 at f = 100 px bends back 111 px from the centre, and the share it reaches is the
    share of the field of view inside that circle."""
    from endopipe.stages.poses.lens import lens_reach

    assert summary(colon_run)["lens_reach"] == 1.0
    ingest = IngestView(colon_run / "01_ingest")
    bent = Camera(
        width=320, height=256, fx=100.0, fy=100.0, cx=159.5, cy=127.5, model="opencv",
        dist=[-0.12, 0.0, 0.0, 0.0],
    )  # fmt: skip
    fov = ingest.fov() > 127
    v, u = np.mgrid[0:256, 0:320]
    inside = np.hypot(u - 159.5, v - 127.5) < 100.0 / np.sqrt(0.36) * (2 / 3)
    share = lens_reach(bent, ingest)
    assert share is not None and abs(share - (fov & inside).sum() / fov.sum()) < 0.01
    assert 0.3 < share < 0.7  # about half: a 111-px circle in a 320x256 frame


def test_sfm_observations_give_the_true_depth_of_their_pixels(colon: Path, colon_run: Path) -> None:
    """The tracks the NeRF's sparse-depth loss uses: frame, OpenCV pixel and point must agree
    with the ground-truth depth of that pixel (a half-pixel or frame mix-up would not)."""
    import torch

    from endopipe.stages.ingest.stage import IngestView
    from endopipe.stages.nerf.sparse_depth import sparse_depth_targets

    poses, ingest = PosesView(colon_run / "02_poses"), IngestView(colon_run / "01_ingest")
    obs = poses.observations({Path(f.file).name: f.index for f in ingest.frames})
    assert obs is not None and len(obs.frame) > 1000
    positions = {i: p for p, i in enumerate(poses.registered)}
    size = (ingest.height, ingest.width)
    cpu = torch.device("cpu")
    sd = sparse_depth_targets(obs, positions, poses.c2w, 2.0, size, 3, 2.0, 0.0, cpu)
    assert sd is not None and 0.5 * len(obs.frame) < len(sd) <= len(obs.frame)
    gt_depth = {
        p: np.load(colon / "gt" / "depth" / f"{ingest.frames[i].source_index:06d}.npy")
        for i, p in positions.items()
    }
    u, v = sd.u.round().long().numpy(), sd.v.round().long().numpy()
    gt = np.array([gt_depth[int(p)][y, x] for p, x, y in zip(sd.frame, u, v, strict=True)])
    ok = gt > 0  # no GT depth where the ray leaves the mesh
    assert ok.mean() > 0.95
    r = 2.0 * sd.z.numpy()[ok] / gt[ok]
    assert abs(np.median(r) - 1.0) < 0.02, np.median(r)
    assert np.median(np.abs(r - 1.0)) < 0.06, np.median(np.abs(r - 1.0))
    # Tighter filters keep fewer rays; a track of one image is never a depth.
    strict = sparse_depth_targets(obs, positions, poses.c2w, 2.0, size, 6, 0.5, 0.0, cpu)
    assert strict is None or len(strict) < len(sd)
    wide = sparse_depth_targets(obs, positions, poses.c2w, 2.0, size, 3, 2.0, 5.0, cpu)
    assert wide is not None and len(wide) < len(sd)
    # An angle the camera never reached keeps the wider half of the points, not none.
    steep = sparse_depth_targets(obs, positions, poses.c2w, 2.0, size, 3, 2.0, 90.0, cpu)
    assert steep is not None and 0.45 * len(sd) < len(steep) <= 0.55 * len(sd)
    assert steep.min_angle < 90.0


def test_points_seen_under_a_narrow_angle_have_the_worse_depth(
    colon: Path, colon_run: Path
) -> None:
    """The triangulation angle the sparse-depth loss filters on tells which SfM depths to trust:
    on the synthetic colon, points whose cameras saw them under less than 3 degrees are further
    from the true depth of their pixel than points seen under more than 6."""
    poses, ingest = PosesView(colon_run / "02_poses"), IngestView(colon_run / "01_ingest")
    obs = poses.observations({Path(f.file).name: f.index for f in ingest.frames})
    assert obs is not None and obs.angle.shape == obs.frame.shape
    assert (obs.angle >= 0).all() and (obs.angle <= 180).all()
    err = relative_depth_error(colon, poses, ingest, obs)
    narrow = np.nanmedian(err[obs.angle < 3.0])
    wide = np.nanmedian(err[obs.angle > 6.0])
    assert narrow > 1.5 * wide, (narrow, wide)


def relative_depth_error(colon: Path, poses: PosesView, ingest: IngestView, obs) -> np.ndarray:
    """|z / true z - 1| of each observation at its (rounded) pixel; NaN where the truth has none."""
    err = np.full(len(obs.frame), np.nan)
    for i in np.unique(obs.frame):
        sel = obs.frame == i
        w2c = np.linalg.inv(poses.c2w[int(i)])
        z = obs.xyz[sel] @ w2c[2, :3] + w2c[2, 3]
        gt = np.load(colon / "gt" / "depth" / f"{ingest.frames[int(i)].source_index:06d}.npy")
        u, v = np.round(obs.uv[sel]).astype(int).T
        inside = (u >= 0) & (u < gt.shape[1]) & (v >= 0) & (v < gt.shape[0])
        g = np.where(inside, gt[v.clip(0, gt.shape[0] - 1), u.clip(0, gt.shape[1] - 1)], 0.0)
        err[np.nonzero(sel)[0]] = np.where(g > 0, np.abs(z / np.maximum(g, 1e-9) - 1.0), np.nan)
    return err


def test_refined_sfm_points_lie_nearer_the_true_depth(colon: Path, colon_run: Path) -> None:
    """The points' multi-view refinement (nerf.loss.sparse_refine) on real COLMAP output: fewer
    of the tracked pixels are far off the true depth than as SfM left them."""
    from endopipe.stages.nerf.point_refine import refine_points

    poses, ingest = PosesView(colon_run / "02_poses"), IngestView(colon_run / "01_ingest")
    obs = poses.observations({Path(f.file).name: f.index for f in ingest.frames})
    assert obs is not None
    grey = {i: ingest.image(i).mean(-1) / 255.0 for i in poses.c2w}
    refined, moved = refine_points(obs, poses.intrinsics, poses.c2w, grey)

    def share_off(o) -> float:
        err = relative_depth_error(colon, poses, ingest, o)
        return float(np.mean(err[np.isfinite(err)] > 0.05))

    before, after = share_off(obs), share_off(refined)
    print(f"moved {moved.mean():.3f}; over 5% off: {before:.3f} -> {after:.3f}")
    assert moved.mean() > 0.3
    assert after < before - 0.03


def test_outputs_follow_the_file_contracts(colon: Path, colon_run: Path) -> None:
    folder = colon_run / "02_poses"
    for name in (
        "cameras.json",
        "points.ply",
        "transforms.json",
        "sparse/cameras.txt",
        "sparse/images.txt",
        "sparse/points3D.txt",
    ):
        assert (folder / name).is_file(), name
    assert not (folder / "colmap").exists(), "the scratch database is removed"
    view = PosesView(folder)
    k = Camera.load(colon / "intrinsics.json")
    assert (view.intrinsics.fx, view.intrinsics.cx, view.intrinsics.cy) == (k.fx, k.cx, k.cy)
    assert view.metric and view.file.units == "mm"
    assert len(view.file.frames) == 20
    # the sparse points are in the GT frame (mm): inside the synthetic lumen, near the path
    points = view.points()
    assert len(points) > 100
    centres = view.centres()
    dist = np.linalg.norm(points[:, None, :] - centres[None], axis=2).min(1)
    assert np.median(dist) < 40.0
    # the COLMAP model and transforms.json hold the same poses as cameras.json
    model = read_colmap_model(folder / "sparse")
    nerf = read_transforms_json(folder / "transforms.json")
    for i in view.registered:
        name = f"{i:06d}.png"
        assert np.allclose(model.c2w[name], view.c2w[i], atol=1e-6)
        assert np.allclose(nerf.c2w[name], view.c2w[i], atol=1e-9)
    tj = json.loads((folder / "transforms.json").read_text())
    assert (folder / tj["frames"][0]["file_path"]).resolve().is_file()
    assert np.allclose(
        np.array(tj["frames"][0]["transform_matrix"])[:3, 1:3],
        -view.c2w[view.registered[0]][:3, 1:3],
    )  # OpenGL: y and z flipped
    assert tj["cx"] == pytest.approx(k.cx + 0.5) and tj["fl_x"] == pytest.approx(k.fx)


def test_second_colmap_run_gives_the_same_poses(colon_run: Path, colon_rerun: Path) -> None:
    """Reproducible within a hair: single-threaded matching and mapping are seeded, but a fresh
    clone's CI once saw two runs differ by ~0.3 degrees (COLMAP's threads), so this bounds the
    difference instead of asking for bitwise equality."""
    first = CamerasFile.model_validate_json((colon_run / "02_poses/cameras.json").read_text())
    second = CamerasFile.model_validate_json((colon_rerun / "02_poses/cameras.json").read_text())
    assert [f.registered for f in first.frames] == [f.registered for f in second.frames]
    a = {f.index: np.array(f.c2w) for f in first.frames if f.registered}
    b = {f.index: np.array(f.c2w) for f in second.frames if f.registered}
    centres = np.array([a[i][:3, 3] for i in sorted(a)])
    path = float(np.linalg.norm(np.diff(centres, axis=0), axis=1).sum())
    for i in a:
        assert np.linalg.norm(a[i][:3, 3] - b[i][:3, 3]) < 0.01 * path
        assert rotation_angle_deg(a[i][:3, :3].T @ b[i][:3, :3]) < 1.0


def test_frames_left_out_join_the_model_again(colon_rerun: Path, tmp_path: Path) -> None:
    """The merge step: continuing a model with relaxed registration adds the missing frames."""
    import pycolmap

    from endopipe.stages.ingest.stage import IngestView
    from endopipe.stages.poses.colmap_sfm import continue_mapping

    folder = colon_rerun / "02_poses"
    shutil.copy(folder / "colmap" / "database.db", tmp_path / "database.db")
    model = pycolmap.Reconstruction(str(folder / "sparse"))
    for frame_id in sorted(model.reg_frame_ids())[-5:]:
        model.deregister_frame(frame_id)
    assert model.num_reg_images() == 15
    ingest = IngestView(colon_rerun / "01_ingest")
    quiet = lambda label, total: nullcontext(lambda n=1, info=None: None)  # noqa: E731
    merged = continue_mapping(
        tmp_path / "database.db",
        model,
        ingest.folder / "frames",
        tmp_path,
        PosesConfig(),
        ingest.intrinsics,
        20,
        quiet,
    )
    assert merged.num_reg_images() == 20


def test_the_focal_guess_of_an_estimated_camera_is_the_configured_one(
    colon_rerun: Path, tmp_path: Path
) -> None:
    """`poses.focal_factor` starts self-calibration (C3VD: 0.5 found the scope's 45 degrees at
    half the frame height where COLMAP's 1.2 settled at 27)."""
    import pycolmap

    from endopipe.stages.ingest.stage import IngestView
    from endopipe.stages.poses.colmap_sfm import extract, prepare_images

    ingest = IngestView(colon_rerun / "01_ingest")
    names = list(ingest.index_by_name())[:3]
    assert PosesConfig().focal_factor == 0.5  # a scope's 90 degrees, not COLMAP's 45
    cfg = PosesConfig(focal_factor=0.7)
    images, masks = prepare_images(ingest, names, tmp_path, cfg)
    extract(tmp_path / "database.db", images, masks, names, cfg, None)
    with pycolmap.Database.open(tmp_path / "database.db") as db:
        (camera,) = db.read_all_cameras()
    assert camera.model.name == "SIMPLE_RADIAL"
    assert camera.params[0] == pytest.approx(0.7 * max(camera.width, camera.height))


def test_source_gt_reproduces_the_ground_truth_exactly(colon: Path, tmp_path: Path) -> None:
    code, _ = run(None, colon, tmp_path, "poses.source=gt", "poses.triangulate_known=false")
    assert code == 0
    view = PosesView(tmp_path / "colon" / "02_poses")
    gt = gt_poses(colon)
    assert view.registered == list(range(20))
    for i in view.registered:
        assert np.array_equal(view.c2w[i], gt[i])
    assert view.intrinsics == Camera.load(colon / "intrinsics.json").model_copy(
        update={"dist": None}
    )
    s = summary(tmp_path / "colon")
    assert s["source"] == "gt" and s["metric"] and s["ate_mm"] < 1e-9
    assert s["points"] == 0 and not (tmp_path / "colon" / "02_poses" / "points.ply").exists()


def test_source_gt_triangulates_points_on_the_wall(tmp_path: Path) -> None:
    """Known poses: points triangulated from them lie on the true wall, and the centerline stage
    measures the radius from them instead of falling back to its default."""
    from endopipe.stages.io.ground_truth import GroundTruth
    from endopipe.stages.surface.evaluate import point_to_surface
    from endopipe.synth import SynthConfig, generate_case

    case = tmp_path / "small"
    generate_case(case, SynthConfig(seed=0, frames=16, width=160, height=128))
    wd = tmp_path / "wd"
    args = ["run", str(case), "--workdir", str(wd), "--until", "centerline", "--quiet"]
    assert main([*args, "--set", "poses.source=gt"]) == 0
    s = summary(wd / "small")
    view = PosesView(wd / "small" / "02_poses")
    points = view.points()
    assert s["points"] == len(points) > 200, s  # 345 measured
    assert view.c2w[0].tolist() == gt_poses(case)[0].tolist()  # the poses stay as given
    gt = GroundTruth(case / "gt")
    true_radius = float(np.mean(gt.centerline()[1]))  # ~14 mm
    mesh = trimesh.load(gt.mesh_path())
    dist = point_to_surface(points, mesh.vertices, mesh.faces)
    assert np.median(dist) < 0.08 * true_radius, np.median(dist)  # 0.84 mm (6%) measured
    line = json.loads((wd / "small" / "03_centerline" / "manifest.json").read_text())["summary"]
    assert line["radius_source"] == "points", line
    assert abs(line["mean_radius"] - true_radius) < 0.1 * true_radius, line  # 4.6% measured


def test_source_file_reads_a_colmap_model_and_a_transforms_json(
    colon: Path, colon_run: Path, tmp_path: Path
) -> None:
    reference = PosesView(colon_run / "02_poses")
    for path in (colon_run / "02_poses" / "sparse", colon_run / "02_poses" / "transforms.json"):
        wd = tmp_path / path.name
        code, _ = run(None, colon, wd, "poses.source=file", f"poses.file={path}")
        assert code == 0, path
        view = PosesView(wd / "colon" / "02_poses")
        assert view.registered == reference.registered
        for i in view.registered:
            assert np.allclose(view.c2w[i], reference.c2w[i], atol=1e-5)
        assert view.intrinsics.fx == pytest.approx(reference.intrinsics.fx)
        assert view.intrinsics.cx == pytest.approx(reference.intrinsics.cx)
        if path.is_dir():  # the model's own points are kept
            assert len(view.points()) == len(reference.points())
        else:  # transforms.json has none: triangulated from its poses
            assert summary(wd / "colon")["points"] > 100


def test_a_models_tracks_are_kept_for_the_frames_it_poses(
    colon: Path, colon_run: Path, tmp_path: Path
) -> None:
    """A COLMAP model given as poses.file keeps its tracks (the SfM-point depth and the lumen
    fit read them) for a case of a stretch of its frames, matched by the number in their name
    (their position in the input): each frame sees the points it saw in the whole model that
    another frame of the stretch sees too."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(colon_run / "02_poses" / "sparse"))
    keep_images(rec, {im.name: f"frame_{int(im.name[:6]):04d}.jpg" for im in rec.images.values()})
    (tmp_path / "model").mkdir()
    rec.write_text(str(tmp_path / "model"))
    stretch = list(range(5, 15))
    model = f"poses.file={tmp_path / 'model'}"
    frames = f"ingest.frames=[{','.join(map(str, stretch))}]"
    code, _ = run(None, colon, tmp_path, "poses.source=file", model, frames)
    assert code == 0
    case = tmp_path / "colon"
    view, ingest = PosesView(case / "02_poses"), IngestView(case / "01_ingest")
    ref = PosesView(colon_run / "02_poses")
    ref_obs = ref.observations(IngestView(colon_run / "01_ingest").index_by_name())
    obs = view.observations(ingest.index_by_name())
    assert obs is not None and view.registered == list(range(len(stretch)))
    for i, source in enumerate(stretch):
        mine = {tuple(np.round(uv, 3)) for uv in obs.uv[obs.frame == i]}
        theirs = {tuple(np.round(uv, 3)) for uv in ref_obs.uv[ref_obs.frame == source]}
        assert mine <= theirs and len(mine) >= 0.5 * len(theirs), (i, len(mine), len(theirs))
    kept = pycolmap.Reconstruction(str(case / "02_poses" / "sparse"))
    assert kept.num_images() == len(stretch)  # the tracks hold these frames only
    assert summary(case)["points"] == kept.num_points3D() > 500  # 975 of the model's 1,528


def test_source_file_missing_is_one_line(colon: Path, tmp_path: Path, capsys) -> None:
    missing = f"poses.file={tmp_path / 'nope'}"
    code, out = run(capsys, colon, tmp_path, "poses.source=file", missing)
    assert_one_line_failure(code, out, "poses.file not found")
    assert not (tmp_path / "colon" / "02_poses").exists()


def test_unreadable_ground_truth_poses_are_one_line(colon: Path, tmp_path: Path, capsys) -> None:
    case = tmp_path / "colon"
    shutil.copytree(colon, case)
    data = json.loads((case / "gt" / "poses.json").read_text())
    data["poses"][3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]  # not a 4x4
    (case / "gt" / "poses.json").write_text(json.dumps(data))
    code, out = run(capsys, case, tmp_path / "wd", "poses.source=gt")
    assert_one_line_failure(code, out, "cannot read the ground-truth poses")


# ---------------------------------------------------------------- the quality gate


def test_frames_of_pure_noise_fail_the_quality_gate(tmp_path: Path, capsys) -> None:
    rng = np.random.default_rng(0)
    folder = tmp_path / "noise"
    folder.mkdir()
    for i in range(12):
        grey = rng.integers(0, 256, (96, 128), dtype=np.uint8)
        grey = cv2.GaussianBlur(grey, (3, 3), 0)  # independent noise, still SIFT-rich
        cv2.imwrite(str(folder / f"{i:03d}.png"), cv2.merge([grey, grey, grey]))
    wd = tmp_path / "wd"
    code, out = run(capsys, folder, wd, "ingest.drop_blurred=false")
    assert_one_line_failure(code, out, "registered 0/12 frames (0%) < 70%")
    assert code == StageFailed.exit_code
    assert "ingest.stride" in out and "--intrinsics" in out
    assert (wd / "noise" / "01_ingest").is_dir()
    assert not list((wd / "noise").glob("*02_poses*")), "no 02_poses folder, not even a temp one"


# ---------------------------------------------------------------- slow: bigger and real inputs


@pytest.mark.slow
def test_synthetic_colon_60_frames(tmp_path: Path) -> None:
    from endopipe.synth import SynthConfig, generate_case

    generate_case(tmp_path / "colon60", SynthConfig(seed=0, frames=60, width=320, height=256))
    code, _ = run(None, tmp_path / "colon60", tmp_path / "wd")
    assert code == 0
    s = summary(tmp_path / "wd" / "colon60")
    assert s["registered_fraction"] >= 0.9 and s["ate_percent_of_path"] <= 1.0, s


@pytest.mark.slow
def test_real_c3vd_frames_register(shared_data: Path, tmp_path: Path) -> None:
    rgb = shared_data / "c3vd_v3_preview" / "rgb"
    code, _ = run(None, rgb, tmp_path)
    assert code == 0
    s = summary(tmp_path / "rgb")
    assert s["total"] == 75 and s["registered_fraction"] >= 0.8, s
    assert not s["metric"] and s["intrinsics"] == "estimated"


@pytest.mark.slow
def test_laparoscopy_video_registers_or_fails_in_one_line(
    shared_data: Path, tmp_path: Path, capsys
) -> None:
    video = shared_data / "laparoscopy_rvimlab" / "endo.mp4"
    code, out = run(capsys, video, tmp_path)
    if code == 0:
        assert summary(tmp_path / "endo")["registered_fraction"] >= 0.7
    else:
        assert_one_line_failure(code, out, "registered")
        assert code == StageFailed.exit_code
