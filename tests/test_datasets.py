"""Data set readers: small fixtures written in each data set's own layout and encoding, read
back through open_input and the ground-truth protocol (depth and poses within quantisation)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile
from scipy.spatial.transform import Rotation

from endopipe.pipeline.errors import InputError
from endopipe.stages.io import c3vd, simcol3d
from endopipe.stages.io.cases import detect_format, find_cases
from endopipe.stages.io.datasets import open_ground_truth
from endopipe.stages.io.ground_truth import GroundTruth, GroundTruthSource
from endopipe.stages.io.images import ImageFolderSource
from endopipe.stages.io.sources import open_input
from tests.conftest import textured_frames, write_video

W, H, N = 128, 96, 8
FLIP_Y = np.diag([1.0, -1.0, 1.0, 1.0])


# ---------------------------------------------------------------- truths and fixture writers


def true_depth_mm(i: int, scale: float = 1.0) -> np.ndarray:
    """A smooth depth field (mm) with an invalid (0) corner, different for every frame."""
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    d = (20.0 + 30.0 * u / W + 10.0 * v / H + 2.5 * i) * scale
    d[:6, :6] = 0.0
    return d


def true_poses(n: int = N, seed: int = 0) -> list[np.ndarray]:
    """OpenCV camera-to-world poses in mm: random rotations along a path."""
    rots = Rotation.random(n, random_state=seed).as_matrix()
    out = []
    for i in range(n):
        c2w = np.eye(4)
        c2w[:3, :3] = rots[i]
        c2w[:3, 3] = [8.0 * np.sin(i / 2.0), 5.0 * np.cos(i / 3.0), 3.0 + 2.0 * i]  # not flat
        out.append(c2w)
    return out


def write_hamlyn(seq: Path, n: int = N, seed: int = 0, layout: str = "rectified") -> Path:
    """rectifiedNN/image01/*.jpg, image02/*.jpg, depth01/*.png (uint16 mm), intrinsics.txt 3x4;
    layout "edm": color/*.jpg, depth/*.png, intrinsics.txt (the Endo-Depth-and-Motion release)."""
    frames = textured_frames(n, W, H, seed=seed)
    left, right, depth_dir = ("image01", "image02", "depth01")
    if layout == "edm":
        left, right, depth_dir = ("color", None, "depth")
    for sub in (left, right, depth_dir):
        if sub:
            (seq / sub).mkdir(parents=True, exist_ok=True)
    for i, rgb in enumerate(frames):
        bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
        cv2.imwrite(str(seq / left / f"{i:010d}.jpg"), bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
        if right:
            cv2.imwrite(str(seq / right / f"{i:010d}.jpg"), np.roll(bgr, 3, axis=1))
        depth = np.round(true_depth_mm(i)).astype(np.uint16)
        cv2.imwrite(str(seq / depth_dir / f"{i:010d}.png"), depth)
    (seq / "intrinsics.txt").write_text(
        "100.5 0 63.25 0\n0 101.0 47.75 0\n0 0 1 0\n"  # a 3x4 projection, as released
    )
    return seq


def write_c3vd(seq: Path, n: int = N, seed: int = 0, numbers: list[int] | None = None) -> Path:
    """NNNN_color.png, NNNN_depth.tiff (uint16, v = mm / 100 * 65535), pose.txt column-major.

    Colour files are not zero padded and depth files are (copies of C3VD differ)."""
    seq.mkdir(parents=True, exist_ok=True)
    numbers = numbers if numbers is not None else list(range(n))
    frames = textured_frames(len(numbers), W, H, seed=seed)
    poses = true_poses(max(numbers) + 1, seed=seed)
    for k, num in enumerate(numbers):
        cv2.imwrite(str(seq / f"{num}_color.png"), cv2.cvtColor(frames[k], cv2.COLOR_RGB2BGR))
        raw = np.round(true_depth_mm(num) / 100.0 * 65535.0).astype(np.uint16)
        tifffile.imwrite(seq / f"{num:04d}_depth.tiff", raw)
    lines = [",".join(repr(float(v)) for v in c2w.T.reshape(-1)) for c2w in poses]
    (seq / "pose.txt").write_text("\n".join(lines) + "\n")
    return seq


def write_simcol(colon: Path, sid: str = "S1", n: int = N, seed: int = 0) -> Path:
    """SyntheticColon_X/{cam.txt, SavedPosition_S1.txt, SavedRotationQuaternion_S1.txt,
    Frames_S1/FrameBuffer_NNNN.png (RGBA), Frames_S1/Depth_NNNN.png (png/255/256*20 cm)}."""
    frames_dir = colon / f"Frames_{sid}"
    frames_dir.mkdir(parents=True, exist_ok=True)
    for i, rgb in enumerate(textured_frames(n, W, H, seed=seed)):
        bgra = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGRA)
        cv2.imwrite(str(frames_dir / f"FrameBuffer_{i:04d}.png"), bgra)
        raw = np.round(true_depth_mm(i, 0.5) / 10.0 / 20.0 * 255.0 * 256.0).astype(np.uint16)
        cv2.imwrite(str(frames_dir / f"Depth_{i:04d}.png"), raw)
    pos_lines, rot_lines = [], []
    for c2w in true_poses(n, seed=seed):
        unity = FLIP_Y @ c2w @ FLIP_Y  # right-handed OpenCV -> left-handed Unity
        x, y, z = (float(v) for v in unity[:3, 3] / 10.0)  # mm -> cm
        qx, qy, qz, qw = (float(v) for v in Rotation.from_matrix(unity[:3, :3]).as_quat())
        pos_lines.append(f"{x!r} {y!r} {z!r}")
        rot_lines.append(f"{qx!r} {qy!r} {qz!r} {qw!r}")
    (colon / f"SavedPosition_{sid}.txt").write_text("\n".join(pos_lines) + "\n")
    (colon / f"SavedRotationQuaternion_{sid}.txt").write_text("\n".join(rot_lines) + "\n")
    (colon / "cam.txt").write_text("110.0 0 63.5 0 112.0 47.5 0 0 1\n")
    return frames_dir


def write_endopipe_case(case: Path, n: int = N) -> Path:
    case.mkdir(parents=True, exist_ok=True)
    write_video(case / "video.mp4", textured_frames(n, W, H))
    intr = {"width": W, "height": H, "fx": 90.0, "fy": 90.0, "cx": 63.5, "cy": 47.5}
    (case / "intrinsics.json").write_text(json.dumps(intr))
    (case / "gt" / "depth").mkdir(parents=True)
    for i in range(n):
        np.save(case / "gt" / "depth" / f"{i:06d}.npy", true_depth_mm(i).astype(np.float32))
    poses = [p.tolist() for p in true_poses(n)]
    (case / "gt" / "poses.json").write_text(
        json.dumps({"convention": "opencv_c2w", "units": "mm", "poses": poses})
    )
    return case


def assert_poses_close(got: list[np.ndarray], want: list[np.ndarray], atol: float) -> None:
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w, atol=atol)
        assert np.linalg.det(g[:3, :3]) == pytest.approx(1.0, abs=1e-9)  # a proper rotation


# ---------------------------------------------------------------- Hamlyn


@pytest.mark.parametrize("layout", ["rectified", "edm"])
def test_hamlyn_reader_frames_intrinsics_and_pseudo_depth(tmp_path: Path, layout: str) -> None:
    seq = write_hamlyn(tmp_path / "rectified01", layout=layout)
    source = open_input(seq)
    assert source.kind == "hamlyn" and source.frame_count() == N
    frames = list(source.frames())
    assert [f.source_index for f in frames] == list(range(N))
    assert frames[0].rgb.shape == (H, W, 3)
    truth = textured_frames(N, W, H)
    err = [np.abs(frames[3].rgb.astype(int) - t).mean() for t in truth]
    assert err[3] < 10 and int(np.argmin(err)) == 3  # the left jpg of frame 3
    k = source.intrinsics
    assert (k.width, k.height, k.fx, k.fy, k.cx, k.cy) == (W, H, 100.5, 101.0, 63.25, 47.75)

    gt = source.ground_truth()
    assert isinstance(gt, GroundTruthSource)
    assert (gt.dataset, gt.kind, gt.units) == ("hamlyn", "pseudo", "mm")
    assert not gt.has_poses() and gt.poses() == []
    for i in (0, N - 1):
        d = gt.depth(i)
        assert d.dtype == np.float32 and d.shape == (H, W)
        np.testing.assert_array_equal(d, np.round(true_depth_mm(i)))  # integer mm, exact
        assert d[0, 0] == 0  # invalid stays 0
    assert gt.depth(N) is None
    assert open_ground_truth(source.gt_dir).kind == "pseudo"  # what case.json's gt_dir gives


def test_a_folder_of_color_images_alone_is_not_hamlyn(tmp_path: Path) -> None:
    """color/ is a common folder name: without intrinsics.txt it is a folder of images."""
    seq = write_hamlyn(tmp_path / "rectified05", n=3, layout="edm")
    (seq / "intrinsics.txt").unlink()
    assert detect_format(seq) != "hamlyn"
    assert detect_format(seq / "color") == "images"


def test_hamlyn_intrinsics_3x3_and_padding_mismatch(tmp_path: Path) -> None:
    seq = write_hamlyn(tmp_path / "rectified07", n=4)
    (seq / "intrinsics.txt").write_text("200 0 60\n0 210 50\n0 0 1\n")
    for f in (seq / "depth01").iterdir():  # depth named with other zero padding
        f.rename(f.with_name(f"{int(f.stem)}.png"))
    source = open_input(seq)
    assert (source.intrinsics.fx, source.intrinsics.fy, source.intrinsics.cy) == (200, 210, 50)
    np.testing.assert_array_equal(source.ground_truth().depth(2), np.round(true_depth_mm(2)))


# ---------------------------------------------------------------- C3VD


def test_c3vd_reader_round_trip(tmp_path: Path) -> None:
    seq = write_c3vd(tmp_path / "cecum_t1_a")
    source = open_input(seq)
    assert source.kind == "c3vd" and source.frame_count() == N
    assert source.intrinsics is None  # C3VD ships no pinhole intrinsics
    frames = list(source.frames())
    np.testing.assert_array_equal(frames[5].rgb, textured_frames(N, W, H)[5])  # png: exact
    gt = source.ground_truth()
    assert isinstance(gt, GroundTruthSource) and (gt.dataset, gt.kind) == ("c3vd", "exact")
    step = 100.0 / 65535.0
    for i in range(N):
        d = gt.depth(i)
        assert d.dtype == np.float32
        assert np.abs(d - true_depth_mm(i)).max() <= step / 2 + 1e-4
        assert d[0, 0] == 0
    assert gt.has_poses()
    assert_poses_close(gt.poses(), true_poses(N), atol=1e-9)  # repr() text: exact


def test_c3vd_pose_is_column_major() -> None:
    c2w = np.eye(4)
    c2w[:3, 3] = [10.0, 20.0, 30.0]
    line = "1,0,0,0,0,1,0,0,0,0,1,0,10,20,30,1"  # translation in values 13-15, as in C3VD
    np.testing.assert_array_equal(c3vd.parse_pose_line(line), c2w)
    np.testing.assert_array_equal(c3vd.parse_pose_line(c3vd.format_pose_line(c2w)), c2w)


def test_c3vd_numeric_order_and_pose_lines(tmp_path: Path) -> None:
    seq = write_c3vd(tmp_path / "sigmoid_t3_b", numbers=[10, 2, 1])
    source = open_input(seq)
    assert [f.name for f in source.files] == ["1_color.png", "2_color.png", "10_color.png"]
    gt = source.ground_truth()
    # source_index 2 is frame number 10: its depth file and pose line 10
    assert np.abs(gt.depth(2) - true_depth_mm(10)).max() < 0.01
    assert_poses_close(gt.poses(), [true_poses(11)[n] for n in (1, 2, 10)], atol=1e-9)


def test_c3vd_depth_encoding_helpers() -> None:
    mm = np.array([[0.0, 0.5, 37.123, 99.99]])
    back = c3vd.decode_depth(c3vd.encode_depth(mm))
    assert np.abs(back - mm).max() <= 100.0 / 65535.0 / 2 + 1e-6
    # full scale is C3VD's clamp (farther than 100 mm, or no surface): unknown, not 100 mm
    assert c3vd.encode_depth(np.array([100.0]))[0] == 65535
    assert c3vd.decode_depth(np.array([65535], np.uint16))[0] == 0.0


# ---------------------------------------------------------------- SimCol3D


def test_simcol3d_reader_round_trip(tmp_path: Path) -> None:
    frames_dir = write_simcol(tmp_path / "SyntheticColon_I")
    source = open_input(frames_dir)
    assert source.kind == "simcol3d" and source.frame_count() == N
    assert all(f.name.startswith("FrameBuffer_") for f in source.files)  # not Depth_*.png
    frames = list(source.frames())
    assert frames[0].rgb.shape == (H, W, 3)  # RGBA png -> RGB
    np.testing.assert_array_equal(frames[2].rgb, textured_frames(N, W, H)[2])
    k = source.intrinsics
    assert (k.width, k.height, k.fx, k.fy, k.cx, k.cy) == (W, H, 110.0, 112.0, 63.5, 47.5)
    gt = source.ground_truth()
    assert isinstance(gt, GroundTruthSource) and (gt.dataset, gt.kind) == ("simcol3d", "exact")
    step = 200.0 / (255.0 * 256.0)  # mm per png level
    for i in range(N):
        assert np.abs(gt.depth(i) - true_depth_mm(i, 0.5)).max() <= step / 2 + 1e-4
    assert_poses_close(gt.poses(), true_poses(N), atol=1e-9)
    assert open_ground_truth(frames_dir).dataset == "simcol3d"


def test_simcol3d_conversion_round_trip() -> None:
    for c2w in true_poses(20, seed=7):
        position_cm, quat = simcol3d.opencv_to_unity(c2w)
        np.testing.assert_allclose(simcol3d.unity_to_opencv(position_cm, quat), c2w, atol=1e-12)
    # and the other way: Unity -> OpenCV -> Unity
    q = Rotation.random(random_state=3).as_quat()
    pos, back = simcol3d.opencv_to_unity(simcol3d.unity_to_opencv([1.0, 2.0, 3.0], q))
    np.testing.assert_allclose(pos, [1.0, 2.0, 3.0], atol=1e-12)
    assert np.allclose(back, q, atol=1e-12) or np.allclose(back, -q, atol=1e-12)


def test_simcol3d_conversion_means_the_right_thing() -> None:
    """Unity: x right, y up, z forward (left-handed). Known camera poses, by hand."""
    s = np.sqrt(0.5)
    # Yaw +90 deg about Unity's up axis turns the view from +z to +x (left-handed rule).
    c2w = simcol3d.unity_to_opencv([1.0, 2.0, 3.0], [0.0, s, 0.0, s])
    np.testing.assert_allclose(c2w[:3, 2], [1, 0, 0], atol=1e-12)  # looks along world +x
    np.testing.assert_allclose(c2w[:3, 1], [0, 1, 0], atol=1e-12)  # image-down = Unity down
    np.testing.assert_allclose(c2w[:3, 3], [10.0, -20.0, 30.0], atol=1e-12)  # cm -> mm, y flip
    # Pitch +90 deg about Unity's x axis looks at the Unity floor: world +y after the flip.
    c2w = simcol3d.unity_to_opencv([0.0, 0.0, 0.0], [s, 0.0, 0.0, s])
    np.testing.assert_allclose(c2w[:3, 2], [0, 1, 0], atol=1e-12)
    # Identity: the OpenCV camera's x is right, y down (Unity's -y), z forward.
    c2w = simcol3d.unity_to_opencv([0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])
    np.testing.assert_allclose(c2w, np.eye(4), atol=1e-12)


def test_simcol3d_depth_encoding() -> None:
    raw = np.array([[0, 255 * 256, 65535]], np.uint16)
    np.testing.assert_allclose(simcol3d.decode_depth(raw), [[0.0, 200.0, 65535 / 65280 * 200]])


# ---------------------------------------------------------------- endopipe case folders


def test_endopipe_case_ground_truth_through_protocol(tmp_path: Path) -> None:
    case = write_endopipe_case(tmp_path / "case01")
    source = open_input(case)
    assert source.kind == "case"
    gt = source.ground_truth()
    assert isinstance(gt, GroundTruth) and isinstance(gt, GroundTruthSource)
    assert (gt.dataset, gt.kind, gt.units) == ("endopipe", "exact", "mm")
    np.testing.assert_array_equal(gt.depth(4), true_depth_mm(4).astype(np.float32))
    assert_poses_close(gt.poses(), true_poses(N), atol=1e-12)


# ---------------------------------------------------------------- evaluation through the protocol


@pytest.mark.parametrize("reader", ["c3vd", "simcol3d", "case", "hamlyn"])
def test_ground_truth_evaluates_correctly(tmp_path: Path, reader: str) -> None:
    """An estimate equal to the truth up to a similarity (what monocular methods give) scores
    ~0 against each reader's ground truth: conventions and units line up."""
    from endopipe.stages.metrics.depth import pose_metrics

    writers = {
        "c3vd": lambda: write_c3vd(tmp_path / "seq"),
        "simcol3d": lambda: write_simcol(tmp_path / "SyntheticColon_I"),
        "case": lambda: write_endopipe_case(tmp_path / "case"),
        "hamlyn": lambda: write_hamlyn(tmp_path / "rectified01"),
    }
    gt = open_input(writers[reader]()).ground_truth()
    step_mm = {"c3vd": 100 / 65535, "simcol3d": 200 / 65280, "case": 0.0, "hamlyn": 1.0}[reader]
    for i in range(N):  # median-scaled depth of a scaled truth: AbsRel at quantisation level
        est, ref = true_depth_mm(i) * 0.37, gt.depth(i)
        valid = ref > 0
        assert valid.mean() > 0.99 and not valid[0, 0]  # the invalid corner stays invalid
        est = est * np.median(ref[valid]) / np.median(est[valid])
        abs_rel = np.mean(np.abs(est[valid] - ref[valid]) / ref[valid])
        assert abs_rel <= step_mm / ref[valid].min() + 1e-6, (i, abs_rel)
    if reader == "hamlyn":
        assert not gt.has_poses()
        return
    R = Rotation.from_euler("xyz", [20, -35, 50], degrees=True).as_matrix()
    sim3 = np.eye(4)
    sim3[:3, :3], sim3[:3, 3] = 0.01 * R, [3.0, -1.0, 2.0]  # another frame, another unit
    est = {}
    for i, c2w in enumerate(true_poses(N)):
        e = sim3 @ c2w
        e[:3, :3] = R @ c2w[:3, :3]  # rotations stay rotations
        est[i] = e
    m = pose_metrics(est, dict(enumerate(gt.poses())))
    assert m["ate"] < 1e-6 and m["rre_deg"] < 1e-6 and m["sim3_scale"] == pytest.approx(100.0)
    if reader == "simcol3d":  # without the handedness flip the same estimate would be wrong
        raw = pose_metrics(est, dict(enumerate(FLIP_Y @ p @ FLIP_Y for p in gt.poses())))
        assert raw["rre_deg"] > 1.0 and raw["ate"] > 0.1


# ---------------------------------------------------------------- detection and --format


def test_detection_finds_every_case_and_names_them(tmp_path: Path) -> None:
    root = tmp_path / "data"
    write_hamlyn(root / "hamlyn" / "rectified01", n=3)
    write_hamlyn(root / "hamlyn" / "rectified02", n=3, layout="edm")
    write_c3vd(root / "c3vd" / "cecum_t1_a", n=3)
    write_simcol(root / "SimCol3D" / "SyntheticColon_I", n=3)
    write_simcol(root / "SimCol3D" / "SyntheticColon_II", n=3)
    write_endopipe_case(root / "cases" / "colon01", n=3)
    (root / "videos").mkdir()
    write_video(root / "videos" / "clip.mp4", textured_frames(3, W, H))
    loose = root / "stills"
    loose.mkdir()
    for i, rgb in enumerate(textured_frames(3, W, H)):
        cv2.imwrite(str(loose / f"{i}.png"), rgb)
    (root / ".hidden").mkdir()
    write_video(root / ".hidden" / "skip.mp4", textured_frames(3, W, H))
    found = {c.name: c.format for c in find_cases(root)}
    assert found == {
        "c3vd__cecum_t1_a": "c3vd",
        "cases__colon01": "case",
        "hamlyn__rectified01": "hamlyn",
        "hamlyn__rectified02": "hamlyn",
        "SimCol3D__SyntheticColon_I__Frames_S1": "simcol3d",
        "SimCol3D__SyntheticColon_II__Frames_S1": "simcol3d",
        "stills": "images",
        "videos__clip": "video",
    }
    # one sequence given directly is one case named after it
    assert [(c.name, c.format) for c in find_cases(root / "hamlyn" / "rectified01")] == [
        ("rectified01", "hamlyn")
    ]
    assert detect_format(root / "cases" / "colon01" / "video.mp4") == "case"
    # --format: only what that reader accepts
    assert [c.name for c in find_cases(root, "c3vd")] == ["c3vd__cecum_t1_a"]
    # the workdir inside the folder is skipped
    assert "stills" not in {c.name for c in find_cases(root, skip=(loose,))}


def test_format_override(tmp_path: Path) -> None:
    seq = write_hamlyn(tmp_path / "rectified02", n=3)
    with pytest.raises(InputError, match="not a c3vd sequence"):
        open_input(seq, format="c3vd")
    left = open_input(seq / "image01", format="images")
    assert isinstance(left, ImageFolderSource) and left.gt_dir is None
    with pytest.raises(InputError, match="unknown input format"):
        open_input(seq, format="kitti")
    assert open_input(seq).kind == "hamlyn"
    with pytest.raises(InputError, match="not a hamlyn sequence"):
        open_input(seq / "image01", format="hamlyn")


def test_digest_is_the_frames_not_the_whole_folder(tmp_path: Path) -> None:
    seq = write_hamlyn(tmp_path / "rectified03", n=3)
    before = open_input(seq).digest()
    cv2.imwrite(str(seq / "image02" / "0000000000.jpg"), np.zeros((H, W, 3), np.uint8))
    assert open_input(seq).digest() == before  # the right images are not read
    cv2.imwrite(str(seq / "image01" / "0000000000.jpg"), np.zeros((H, W, 3), np.uint8))
    assert open_input(seq).digest() != before


@pytest.fixture(params=["in place", "through a symlink"])
def c3vd_preview(request: pytest.FixtureRequest, shared_data: Path, tmp_path: Path) -> Path:
    """The shared C3VD preview folder, as it is and through a symlink (a normal data setup)."""
    folder = shared_data / "c3vd_v3_preview"
    if request.param == "in place":
        return folder
    link = tmp_path / "data" / "c3vd_v3_preview"
    link.parent.mkdir()
    link.symlink_to(folder, target_is_directory=True)
    return link


def test_c3vd_preview_is_read_in_place_with_relative_ground_truth(c3vd_preview: Path) -> None:
    folder = c3vd_preview
    assert detect_format(folder) == "c3vd_preview"
    source = open_input(folder)
    # Data sets are read through their real path (it lands in case.json), wherever the link is.
    assert source.frame_count() == 75 and source.gt_dir == folder.resolve()
    gt = open_ground_truth(folder)
    assert gt.kind == "relative" and not gt.has_poses()
    first = next(iter(source.frames()))
    depth = gt.depth(0)
    assert depth is not None and depth.shape == first.rgb.shape[:2]
    # Brighter = farther: the lumen's far end (image centre) is brighter than the walls at the
    # octagon's rim.
    h, w = depth.shape
    centre = depth[h // 3 : 2 * h // 3, w // 3 : 2 * w // 3]
    assert np.percentile(centre, 90) > np.median(depth[depth > 0])
    # The codec's ramp from the black outside to the wall (grey 1-17 within 3 px of it; the
    # raw panel's 0.5th percentile is 1-4 on frames 0-74) is no depth: invalid, and the
    # octagon itself is kept (94% of the raw panel is rendered).
    for i in (0, 35, 74):
        depth = gt.depth(i)
        assert np.percentile(depth[depth > 0], 0.5) >= 15
        assert 0.91 < (depth > 0).mean() < 0.94


def test_affine_invariant_metrics_ignore_scale_and_shift_only() -> None:
    from endopipe.stages.metrics.depth import affine_invariant_metrics

    rng = np.random.default_rng(0)
    depth = rng.uniform(5.0, 50.0, (64, 64)).astype(np.float32)
    proxy = 3.0 * depth + 20.0  # an affine proxy, like C3VD's grey panel
    exact = affine_invariant_metrics(depth, proxy)
    assert exact["abs_rel"] < 1e-6 and exact["spearman"] > 0.999
    assert exact["scale"] == pytest.approx(3.0, rel=1e-4)
    wrong = affine_invariant_metrics(1.0 / depth, proxy)  # monotonic but inverted
    assert wrong["spearman"] < -0.999 and wrong["abs_rel"] > 0.05
    noisy = affine_invariant_metrics(depth * rng.uniform(0.9, 1.1, depth.shape), proxy)
    assert 0.01 < noisy["abs_rel"] < 0.1 and 0.9 < noisy["spearman"] < 1.0


def test_case_ground_truth_is_recorded_by_its_absolute_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A case given by a relative path: case.json's gt_dir still opens from any folder."""
    from endopipe.cli import main

    gt_dir = (write_endopipe_case(tmp_path / "data" / "colon") / "gt").resolve()
    monkeypatch.chdir(tmp_path / "data")
    assert open_input(Path("colon")).gt_dir == gt_dir
    args = ["run", "colon", "--workdir", str(tmp_path / "wd"), "--until", "ingest", "--quiet"]
    assert main(args) == 0
    info = json.loads((tmp_path / "wd" / "colon" / "case.json").read_text())
    assert info["gt_dir"] == str(gt_dir)
