"""EndoNeRF's layout read in place: detection, intrinsics from hwf, frames by number, masks and
depth matched by number, the poses exposed as known (never ground truth) and depth as pseudo."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from endopipe.cli import main
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.datasets import detect_dataset, open_ground_truth
from endopipe.stages.io.sources import open_input

W, H, N = 64, 48, 6


def tissue(rng: np.random.Generator) -> np.ndarray:
    """A textured, saturated pink frame (BGR): tissue, nothing grey."""
    base = np.empty((H, W, 3), np.uint8)
    base[..., 0], base[..., 1], base[..., 2] = 70, 60, 190
    noise = rng.integers(-40, 40, (H, W, 1))
    return np.clip(base.astype(int) + noise, 0, 255).astype(np.uint8)


def endonerf_folder(root: Path, tool_share: float = 0.25, first: int = 0) -> Path:
    """6 frames of 64x48 named as the real data set names them, numbered from `first`; a tool
    covering the left `tool_share` of every frame; depth = 50 + frame number; hwf for 128x96."""
    seq = root / "cutting"
    for sub in ("images", "masks", "depth"):
        (seq / sub).mkdir(parents=True)
    rng = np.random.default_rng(0)
    mask = np.zeros((H, W), np.uint8)
    mask[:, : round(W * tool_share)] = 255
    for n in range(first, first + N):
        cv2.imwrite(str(seq / "images" / f"frame-{n:06d}.color.png"), tissue(rng))
        cv2.imwrite(str(seq / "masks" / f"frame-{n:06d}.mask.png"), mask)
        cv2.imwrite(str(seq / "depth" / f"frame-{n}.depth.png"), np.full((H, W), 50 + n, np.uint8))
    row = np.concatenate(
        [np.hstack([np.eye(3), np.zeros((3, 1)), [[96], [128], [100.0]]]).ravel(), [0, 89]]
    )
    np.save(seq / "poses_bounds.npy", np.tile(row, (N, 1)))
    return seq


def test_the_layout_is_detected_and_read_by_number(tmp_path: Path) -> None:
    seq = endonerf_folder(tmp_path, first=1)
    (seq / "images" / "frame-000006.color.png").rename(seq / "images" / "000006.png")  # any name
    assert detect_dataset(seq) == "endonerf"
    source = open_input(seq)
    assert source.kind == "endonerf"
    names = [f.name for f in source.files]
    assert names[0] == "frame-000001.color.png" and names[-1] == "000006.png"  # by number
    k = source.intrinsics  # hwf says 128x96 with f = 100: half the size, half the focal
    assert (k.width, k.height, k.fx, k.fy) == (64, 48, 50.0, 50.0)
    assert (k.cx, k.cy) == (31.5, 23.5)
    assert source.tool_masks is not None and sorted(source.tool_masks.files) == list(range(N))
    assert source.tool_masks.file(0).name == "frame-000001.mask.png"


def test_poses_are_known_not_ground_truth_and_depth_is_pseudo(tmp_path: Path) -> None:
    seq = endonerf_folder(tmp_path)
    source = open_input(seq)
    assert source.known_poses is not None and len(source.known_poses) == N
    # EndoNeRF's identity read as a NeRF (OpenGL) c2w: OpenCV's y and z flipped
    assert np.allclose(source.known_poses[0], np.diag([1.0, -1.0, -1.0, 1.0]))
    truth = open_ground_truth(source.gt_dir)
    assert truth.kind == "pseudo" and not truth.has_poses()
    assert truth.depth_count() == N
    assert float(truth.depth(2)[0, 0]) == 52.0  # its own units: frame-2.depth.png matched by number


def test_ingest_masks_the_tool_and_keeps_it_per_frame(tmp_path: Path) -> None:
    seq = endonerf_folder(tmp_path, tool_share=0.25)
    args = ["run", str(seq), "--workdir", str(tmp_path / "wd"), "--until", "ingest", "--quiet"]
    assert main([*args, "--set", "ingest.drop_duplicates=false"]) == 0
    view = IngestView(tmp_path / "wd" / "cutting" / "01_ingest")
    assert len(view.frames) == N
    tool = view.tool_mask(0)
    assert tool is not None and tool[:, :16].all() and not tool[:, 16:].any()
    assert (view.mask(0)[tool] == 0).all()
    assert view.frame(0).tool_share == pytest.approx(0.25)
    s = view.summary
    assert s.kind == "endonerf" and s.tool_polarity == "255 = tool"
    assert s.mean_tool_fraction == pytest.approx(0.25) and s.max_tool_fraction == pytest.approx(
        0.25
    )
    assert s.frames_with_tools == N
    assert s.known_poses is not None and "one for all 6 frames" in s.known_poses
    assert len(view.known_poses()) == N
    frames = json.loads((view.folder / "frames.json").read_text())
    assert frames["tools"].startswith("masks/")


def ingest_of(seq: Path, tmp_path: Path) -> IngestView:
    args = ["run", str(seq), "--workdir", str(tmp_path / "wd"), "--until", "ingest", "--quiet"]
    assert main([*args, "--set", "ingest.drop_duplicates=false"]) == 0
    return IngestView(tmp_path / "wd" / seq.name / "01_ingest")


def test_depth_in_unnamed_units_supervises_as_a_relative_prior(tmp_path: Path) -> None:
    """EndoNeRF as released names no unit for depth/: a relative prior, never metric; the
    depth stage is told its scores are against the maps that supervised."""
    seq = endonerf_folder(tmp_path)
    view = ingest_of(seq, tmp_path)
    assert view.has_depth_prior and not view.has_stereo
    assert float(np.median(view.depth_prior(3))) == 53.0  # frame-3.depth.png, as it is
    assert view.truth_supervised(view.ground_truth()) == str((seq / "depth").resolve())


def test_depth_in_millimetres_is_metric_and_unknown_on_the_tool(tmp_path: Path) -> None:
    """endonerf.json saying mm (endopipe's export and synth): the maps are metric depth, taken
    as the stereo rig's would be (stereo/, no baseline), except on the tool: a tool's depth is
    not the tissue's, which is what the field holds and the depth maps publish."""
    seq = endonerf_folder(tmp_path, tool_share=0.25)
    (seq / "endonerf.json").write_text(json.dumps({"depth_scale": 2.0, "units": "mm"}))
    view = ingest_of(seq, tmp_path)
    assert view.has_stereo and not view.has_depth_prior
    depth = view.stereo_depth(4)
    assert depth is not None and depth.shape == (H, W)
    assert not depth[:, :16].any()  # the tool's pixels: unknown
    assert np.allclose(depth[depth > 0], 27.0)  # 54 counts / 2 per mm
    assert (depth[:, 16:] > 0).mean() > 0.9
    info = view.file.stereo
    assert info is not None and info.baseline_mm is None and "given" in info.matcher
    assert view.summary.stereo is not None and "mm by endonerf.json" in view.summary.stereo
    assert view.truth_supervised(view.ground_truth()) == str((seq / "depth").resolve())


def test_known_poses_are_compared_never_scored() -> None:
    """The input's own poses check ours: a moving path after a sim3 (in % of their path), a
    still one by whether ours stand still too."""
    from endopipe.stages.poses.stage import compare_known

    def at(t: np.ndarray) -> np.ndarray:
        m = np.eye(4)
        m[:3, 3] = t
        return m

    path = {i: at(np.array([i, 0.1 * i * i, 0.0])) for i in range(8)}
    ours = {i: at(2.0 * m[:3, 3] + [1, 2, 3] + [0.01 * (-1) ** i, 0, 0]) for i, m in path.items()}
    moving = compare_known(ours, path, "poses_bounds.npy")
    assert moving.agree is None and 0 < moving.ate_percent_of_path < 0.5
    assert "not ground truth" in moving.said
    still = {i: np.diag([1.0, -1.0, -1.0, 1.0]) for i in range(8)}
    assert compare_known({i: np.eye(4) for i in range(8)}, still, "x").agree is True
    check = compare_known(ours, still, "x")
    assert check.agree is False and "unlike ours (moving)" in check.said


def test_poses_from_the_inputs_own_file(tmp_path: Path) -> None:
    """poses.source=known: every frame gets the data set's pose as it is, not a score."""
    from endopipe.stages.poses.view import PosesView

    seq = endonerf_folder(tmp_path)
    args = ["run", str(seq), "--workdir", str(tmp_path / "wd"), "--until", "poses", "--quiet"]
    sets = ["ingest.drop_duplicates=false", "poses.source=known", "poses.motion.check=false"]
    assert main([*args, *[x for s in sets for x in ("--set", s)]]) == 0
    poses = PosesView(tmp_path / "wd" / "cutting" / "02_poses")
    assert len(poses.c2w) == N
    assert all(np.allclose(m, np.diag([1.0, -1.0, -1.0, 1.0])) for m in poses.c2w.values())
    assert poses.summary.source == "known" and poses.summary.known_poses is None
