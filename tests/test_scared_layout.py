"""A SCARED keyframe read as it ships: rectified with its calibration, the right eye as stereo
pairs, the kinematics as known poses, the keyframe's points as depth truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from endopipe.commands.synth import other_layout
from endopipe.pipeline.errors import InputError
from endopipe.stages.io.datasets import detect_dataset, open_dataset
from endopipe.stages.io.ground_truth import open_case_truth
from endopipe.stages.io.scared import ScaredGroundTruth
from endopipe.synth import SynthConfig, generate_case
from endopipe.synth.generate import intrinsics_for

BASELINE_MM = 5.0


@pytest.fixture(scope="module")
def case(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, SynthConfig]:
    out = tmp_path_factory.mktemp("scared") / "keyframe_1"
    cfg = SynthConfig(seed=5, frames=4, width=64, height=48, stereo_baseline_mm=BASELINE_MM)
    generate_case(out, cfg, layout=other_layout("scared", BASELINE_MM))
    return out, cfg


def test_keyframe_reads_with_its_calibration(case: tuple[Path, SynthConfig]) -> None:
    path, cfg = case
    assert detect_dataset(path) == "scared"
    source = open_dataset(path, "scared")
    k, truth = source.intrinsics, intrinsics_for(cfg)
    assert k is not None and (k.width, k.height) == (64, 48) and not k.distorted
    # an identical, already rectified pair: stereoRectify keeps the camera (measured 0 px)
    assert abs(k.fx - truth.fx) < 1e-6 * truth.fx
    assert abs(k.cx - truth.cx) < 1e-6 and abs(k.cy - truth.cy) < 1e-6
    frames = list(source.frames())
    assert len(frames) == 4 and frames[0].rgb.shape == (48, 64, 3)


def test_right_eye_is_the_stereo_pair(case: tuple[Path, SynthConfig]) -> None:
    path, _ = case
    source = open_dataset(path, "scared")
    assert source.stereo is not None
    assert source.stereo.baseline_mm == pytest.approx(BASELINE_MM)
    left = [f.rgb for f in source.frames()]
    right = [source.stereo.right(i) for i in (0, 1, 3)]
    assert all(r is not None and r.shape == (48, 64, 3) for r in right)
    assert source.stereo.right(0) is not None  # asked again from the start
    assert source.stereo.right(9) is None
    # the right eye is another view, not the left one again
    assert np.abs(right[0].astype(int) - left[0].astype(int)).mean() > 2


def test_kinematics_are_known_poses(case: tuple[Path, SynthConfig]) -> None:
    path, _ = case
    source = open_dataset(path, "scared")
    truth = open_case_truth(path / "gt").poses()
    assert source.known_poses is not None and len(source.known_poses) == 4
    assert np.allclose(np.array(source.known_poses), np.array(truth), atol=1e-9)


def test_keyframe_depth_is_the_first_frames_truth(case: tuple[Path, SynthConfig]) -> None:
    path, _ = case
    gt = ScaredGroundTruth(path)
    assert gt.has_depth(0) and not gt.has_depth(1) and gt.depth_count() == 1
    depth = gt.depth(0)
    exact = np.load(path / "gt" / "depth" / "000000.npy")
    assert depth is not None and depth.shape == exact.shape
    both = (depth > 0) & (exact > 0)
    assert both.mean() > 0.95
    assert np.abs(depth[both] - exact[both]).max() < 1e-3


def test_a_calibration_without_the_rig_is_one_line(
    case: tuple[Path, SynthConfig], tmp_path: Path
) -> None:
    path, _ = case
    broken = tmp_path / "kf"
    (broken / "data").mkdir(parents=True)
    (broken / "data" / "rgb.mp4").symlink_to(path / "data" / "rgb.mp4")
    (broken / "endoscope_calibration.yaml").write_text("%YAML:1.0\n---\nfoo: 1\n")
    with pytest.raises(InputError, match="has no M1 or K1"):
        open_dataset(broken, "scared")
