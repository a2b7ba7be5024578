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
