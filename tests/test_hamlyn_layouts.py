"""The Hamlyn reader on each layout users download: the rectified release (nested as its zips
unpack, calibration in calibration/NN/), Endo-Depth-and-Motion's copy (intrinsic/), the stereo
network's 300 mm ceiling, depth folders that are never image cases, and the synth layouts."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from endopipe.cli import main
from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.cases import detect_format, find_cases
from endopipe.stages.io.hamlyn import HamlynGroundTruth
from endopipe.stages.io.sources import open_input
from endopipe.synth.edam_sink import EdamSink
from tests.conftest import textured_frames

W, H, N = 96, 72, 3
K = "100.5 0 47.5\n0 101 35.5\n0 0 1\n"
RT = "0.9999 0.01 0 -5.2\n-0.01 0.9999 0 0.3\n0 0 1 0.1\n"  # [R | t], t in mm


def write_rectified(seq: Path, right: bool = True, depth_mm: float = 120.0) -> list[np.ndarray]:
    """image01/, image02/ (the left shifted: a distinct image), depth01/ (uint16 mm)."""
    frames = textured_frames(N, W, H)
    for sub in ("image01", "depth01") + (("image02",) if right else ()):
        (seq / sub).mkdir(parents=True)
    for i, rgb in enumerate(frames):
        bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
        cv2.imwrite(str(seq / "image01" / f"{i:010d}.png"), bgr)
        if right:
            cv2.imwrite(str(seq / "image02" / f"{i:010d}.png"), np.roll(bgr, -4, axis=1))
        depth = np.full((H, W), depth_mm + i, np.uint16)
        depth[:4, :4] = 0
        cv2.imwrite(str(seq / "depth01" / f"{i:010d}.png"), depth)
    return frames


def release(root: Path) -> Path:
    """hamlyn_data/rectified01/rectified01/ and hamlyn_data/calibration/01/, as released."""
    write_rectified(root / "rectified01" / "rectified01")
    (root / "calibration" / "01").mkdir(parents=True)
    (root / "calibration" / "01" / "intrinsics.txt").write_text(K)
    (root / "calibration" / "01" / "extrinsics.txt").write_text(RT)
    return root / "rectified01"


def test_the_release_nested_with_its_calibration_folder(tmp_path: Path) -> None:
    outer = release(tmp_path / "hamlyn_data")
    source = open_input(outer)  # the outer folder, as the zip unpacks
    assert source.kind == "hamlyn" and source.path == outer / "rectified01"
    k = source.intrinsics
    assert (k.width, k.height, k.fx, k.fy, k.cx, k.cy) == (W, H, 100.5, 101.0, 47.5, 35.5)
    stereo = source.stereo
    assert stereo is not None
    assert stereo.baseline_mm == pytest.approx(np.linalg.norm([-5.2, 0.3, 0.1]))
    left = next(iter(source.frames())).rgb
    np.testing.assert_array_equal(stereo.right(0), np.roll(left, -4, axis=1))
    assert stereo.right(N) is None
    gt = source.ground_truth()
    assert gt.kind == "pseudo" and gt.depth(1)[10, 10] == 121 and gt.depth(1)[0, 0] == 0
    # batch finds one case, named after the outer folder, not the inner one twice
    assert [(c.name, c.format) for c in find_cases(tmp_path)] == [
        ("hamlyn_data__rectified01", "hamlyn")
    ]


def test_right_views_change_the_input_digest(tmp_path: Path) -> None:
    seq = release(tmp_path / "hamlyn_data")
    before = open_input(seq).digest()
    right = seq / "rectified01" / "image02" / "0000000001.png"
    cv2.imwrite(str(right), np.zeros((H, W, 3), np.uint8))
    assert open_input(seq).digest() != before  # the matcher reads them: ingest re-runs


def test_no_baseline_no_stereo_and_bad_ones_refused(tmp_path: Path) -> None:
    seq = tmp_path / "rectified02"
    write_rectified(seq)
    (seq / "intrinsics.txt").write_text(K)
    assert open_input(seq).stereo is None  # right views, but no extrinsics: never guessed
    (seq / "extrinsics.txt").write_text("1 0 0 -0.0052\n0 1 0 0\n0 0 1 0\n")  # metres
    with pytest.raises(InputError, match="baseline of 0.0052 mm"):
        open_input(seq)
    (seq / "extrinsics.txt").write_text("1 0 0 -5\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")  # 4x4
    assert open_input(seq).stereo.baseline_mm == 5.0
    cv2.imwrite(str(seq / "image02" / "0000000000.png"), np.zeros((H, W + 9, 3), np.uint8))
    with pytest.raises(InputError, match="a rectified pair has one size"):
        open_input(seq).stereo.right(0)


def test_edam_copy_with_intrinsic_folder_is_one_case(tmp_path: Path) -> None:
    """EDaM's release: color/, depth/, intrinsic/intrinsic_color.txt (4x4), no intrinsics.txt.
    Read as Hamlyn; batch sees one case, not color/ and depth/ as two image folders."""
    seq = tmp_path / "edam" / "rectified05"
    frames = textured_frames(N, W, H)
    for sub in ("color", "depth", "intrinsic"):
        (seq / sub).mkdir(parents=True)
    for i, rgb in enumerate(frames):
        cv2.imwrite(str(seq / "color" / f"{i:010d}.jpg"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(seq / "depth" / f"{i:010d}.png"), np.full((H, W), 300, np.uint16))
    (seq / "intrinsic" / "intrinsic_color.txt").write_text(
        "90 0 47.5 0\n0 91 35.5 0\n0 0 1 0\n0 0 0 1\n"
    )
    source = open_input(seq)
    assert source.kind == "hamlyn" and source.stereo is None
    assert (source.intrinsics.fx, source.intrinsics.fy) == (90.0, 91.0)
    assert [(c.name, c.format) for c in find_cases(tmp_path / "edam")] == [
        ("rectified05", "hamlyn")
    ]
    assert not source.ground_truth().depth(0).any()  # all saturated: all unknown


def test_the_300_mm_ceiling_is_unknown(tmp_path: Path) -> None:
    seq = tmp_path / "rectified03"
    write_rectified(seq, right=False, depth_mm=299.0)  # frames 0, 1, 2: 299, 300, 301 mm
    (seq / "intrinsics.txt").write_text(K)
    gt = HamlynGroundTruth(seq)
    assert gt.kind == "pseudo"  # a stereo network's estimate, not a measurement
    assert gt.depth(0)[10, 10] == 299.0
    assert not gt.depth(1).any() and not gt.depth(2).any()


def test_depth_folders_are_never_image_cases(tmp_path: Path) -> None:
    root = tmp_path / "data"
    for name in ("depth", "depth01", "Depth02"):
        (root / "a" / name).mkdir(parents=True)
        cv2.imwrite(str(root / "a" / name / "0.png"), np.full((H, W), 50, np.uint16))
        assert detect_format(root / "a" / name) is None
    (root / "b").mkdir()
    for i, rgb in enumerate(textured_frames(N, W, H)):
        cv2.imwrite(str(root / "b" / f"{i}.png"), rgb)
    assert [(c.name, c.format) for c in find_cases(root)] == [("b", "images")]
    assert find_cases(root, "images") == find_cases(root)


def test_synth_edam_layout_saturates_at_300_mm(tmp_path: Path) -> None:
    camera = Camera(width=W, height=H, fx=80.0, fy=80.0, cx=47.5, cy=35.5)
    sink = EdamSink(tmp_path / "rectified06", camera)
    depth = np.full((H, W), 450.0)
    depth[:, : W // 2] = 42.4
    depth[0, 0] = 0.0
    sink.add_frame(textured_frames(1, W, H)[0], depth, None)
    sink.finish(np.eye(4)[None])
    source = open_input(tmp_path / "rectified06")
    assert source.kind == "hamlyn" and source.intrinsics.fx == 80.0
    got = source.ground_truth().depth(0)
    assert got[5, 5] == 42.0 and got[5, -5] == 0.0 and got[0, 0] == 0.0


def test_synth_stereo_hamlyn_with_a_still_camera(tmp_path: Path) -> None:
    out = tmp_path / "rectified07"
    args = ["synth", str(out), "--frames", "2", "--width", "64", "--height", "48"]
    assert main([*args, "--layout", "hamlyn", "--stereo", "--still-camera"]) == 0
    for sub in ("image01", "image02", "depth01"):
        assert len(list((out / sub).iterdir())) == 2
    source = open_input(out)
    assert source.stereo.baseline_mm == 5.0 and source.ground_truth().kind == "exact"
    # a laparoscopic layout's scene is the cavity (walls 12-33 mm away), not the colon, whose
    # near wall (under 11 mm here) a 5 mm rig's right eye partly misses
    depth = source.ground_truth().depth(0)
    assert depth[depth > 0].min() > 15.0
    # the right eye is another view: the same scene shifted, not the left image again
    left, right = next(iter(source.frames())).rgb, source.stereo.right(0)
    assert np.abs(left.astype(int) - right).mean() > 2
    assert main([*args, "--stereo"]) != 0  # endopipe's case folder has no place for it
    assert main([*args, "--layout", "edam", "--stereo"]) != 0
