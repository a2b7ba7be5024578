"""Stereo depth: the matcher against exact truth on a synthetic stereo Hamlyn sequence, its
left-right check on a pair with an occlusion, and the ingest stage writing it (or not).

Measured (scripts/stereo_accuracy.py, 6 frames of 320x256 a seed, seeds 0-3): AbsRel 0.021 to
0.027 against the exact depth, 0.026 to 0.032 against depth01/'s whole millimetres, on 69-75% of
the pixels; at half the size (fx halved) 0.025 to 0.032 on 73-79%.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from endopipe.cli import main
from endopipe.stages.ingest.config import StereoConfig
from endopipe.stages.ingest.stereo import consistent, match_depth
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.hamlyn import HamlynGroundTruth
from endopipe.stages.io.sources import open_input
from tests.stereo_hamlyn import BASELINE_MM, write_stereo_hamlyn

ABS_REL_EXACT = 0.035  # measured 0.021-0.027 over four seeds
ABS_REL_DEPTH01 = 0.04  # measured 0.026-0.032: the truth rounded to whole mm
MIN_COVERAGE = 0.6  # measured 0.69-0.75


@pytest.fixture(scope="module")
def stereo_seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    seq = tmp_path_factory.mktemp("hamlyn") / "rectified01"
    write_stereo_hamlyn(seq, seed=1, frames=4)
    return seq


def abs_rel(depth: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """AbsRel where both have a depth, and the share of the truth's pixels that got one."""
    valid = truth > 0
    got = valid & (depth > 0)
    return float((np.abs(depth[got] - truth[got]) / truth[got]).mean()), got.sum() / valid.sum()


def test_matcher_depth_against_the_truth(stereo_seq: Path) -> None:
    source = open_input(stereo_seq)
    assert source.stereo is not None and source.stereo.baseline_mm == pytest.approx(BASELINE_MM)
    exact, depth01 = source.ground_truth(), HamlynGroundTruth(stereo_seq)
    cfg = StereoConfig()
    rows = []
    for frame in source.frames():
        right = source.stereo.right(frame.source_index)
        depth = match_depth(frame.rgb, right, source.intrinsics.fx, BASELINE_MM, cfg)
        assert depth.dtype == np.float32 and depth.shape == frame.rgb.shape[:2]
        rows.append(
            (
                *abs_rel(depth, exact.depth(frame.source_index)),
                abs_rel(depth, depth01.depth(frame.source_index))[0],
            )
        )
    rel, cover, rel01 = np.mean(rows, axis=0)
    print(f"AbsRel {rel:.4f} (depth01 {rel01:.4f}), coverage {cover:.3f}")
    assert rel < ABS_REL_EXACT and rel01 < ABS_REL_DEPTH01 and cover > MIN_COVERAGE


def test_the_occluded_band_is_unknown_and_the_planes_measured() -> None:
    """A textured plane at disparity 8 behind a square at disparity 24: the band of background
    left of the square that the right eye cannot see gets no depth; the planes get theirs."""
    rng = np.random.default_rng(0)
    h, w, fx, baseline = 120, 200, 100.0, 4.0
    back, front = (
        cv2.GaussianBlur(rng.random((h, w + 64)).astype(np.float32), (0, 0), 1.2) for _ in range(2)
    )
    # The right eye sees the left image's column x at x - disparity.
    left = back[:, 32 : 32 + w].copy()
    left[40:80, 110:150] = front[:, 32 : 32 + w][40:80, 110:150]
    right = back[:, 40 : 40 + w].copy()
    right[40:80, 86:126] = front[:, 56 : 56 + w][40:80, 86:126]

    def rgb(g: np.ndarray) -> np.ndarray:
        return np.repeat((np.clip(g, 0, 1) * 255).astype(np.uint8)[..., None], 3, axis=2)

    depth = match_depth(rgb(left), rgb(right), fx, baseline, StereoConfig(min_disparity_px=2))
    z_back, z_front = fx * baseline / 8, fx * baseline / 24
    assert (depth[45:75, 96:108] == 0).mean() > 0.95  # background hidden from the right eye
    assert np.median(depth[50:70, 115:145]) == pytest.approx(z_front, rel=0.02)
    assert (depth[5:35, 60:190] > 0).mean() > 0.95
    assert np.median(depth[5:35, 60:190]) == pytest.approx(z_back, rel=0.02)


def test_left_right_check() -> None:
    """A left pixel keeps its match only when the right image's match at x - d points back."""
    left = np.array([[np.nan, 2.0, 2.0, 1.0, 3.0, 5.0]], np.float32)
    right = np.array([[2.0, 2.0, 3.0, 2.0, 1.0, 9.0]], np.float32)
    # x=1: d 2 lands outside; x=2: right[0] = 2 agrees; x=3: right[2] = 3 vs 1 disagrees;
    # x=4: right[1] = 2 vs 3 within 1 px; x=5: right[0] = 2 vs 5 disagrees.
    got = consistent(left, right, 1.0)
    assert got.tolist() == [[False, False, True, False, True, False]]
    assert consistent(left, right, 0.5).tolist() == [[False, False, True, False, False, False]]


def ingest(src: Path, wd: Path, *sets: str) -> int:
    args = ["run", str(src), "--workdir", str(wd), "--until", "ingest", "--quiet"]
    return main([*args, *(x for s in sets for x in ("--set", s))])


def test_ingest_writes_metric_stereo_depth_at_the_working_size(
    stereo_seq: Path, tmp_path: Path
) -> None:
    """Frames downscaled 320 -> 160: the depth keeps its millimetres (the disparity halves)."""
    assert ingest(stereo_seq, tmp_path, "ingest.max_size=160") == 0
    view = IngestView(tmp_path / "rectified01" / "01_ingest")
    summary = view.summary
    assert summary.stereo_baseline_mm == pytest.approx(BASELINE_MM)
    assert len(summary.stereo_coverage) == summary.kept == len(view.indices)
    assert summary.stereo_mean_coverage > 0.5
    truth = open_input(stereo_seq).ground_truth()
    for i in view.indices:
        depth = view.stereo_depth(i)
        assert depth.dtype == np.float32 and depth.shape == (view.height, view.width) == (128, 160)
        gt = cv2.resize(truth.depth(view.frame(i).source_index), (160, 128), cv2.INTER_NEAREST)
        rel, cover = abs_rel(depth, gt)
        assert rel < ABS_REL_EXACT + 0.01 and cover > 0.5
        assert view.frame(i).stereo_share == pytest.approx(summary.stereo_coverage[i])
    frames = json.loads((view.folder / "frames.json").read_text())
    assert frames["stereo"]["baseline_mm"] == pytest.approx(BASELINE_MM)


def test_a_monocular_input_gets_no_stereo_depth(
    stereo_seq: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    mono = tmp_path / "rectified02"
    mono.mkdir()
    for sub in ("image01", "depth01", "gt"):
        (mono / sub).symlink_to(stereo_seq / sub)
    (mono / "intrinsics.txt").write_text((stereo_seq / "intrinsics.txt").read_text())
    assert ingest(mono, tmp_path / "wd") == 0
    view = IngestView(tmp_path / "wd" / "rectified02" / "01_ingest")
    assert all(view.stereo_depth(i) is None for i in view.indices)
    assert view.summary.stereo is None and view.summary.stereo_coverage is None
    assert not (view.folder / "stereo").exists()
    assert ingest(mono, tmp_path / "on", "ingest.stereo.mode=on") != 0  # asked for: one line
    assert "no rectified right views" in capsys.readouterr().err


def test_stereo_off_leaves_a_stereo_input_monocular(stereo_seq: Path, tmp_path: Path) -> None:
    assert ingest(stereo_seq, tmp_path, "ingest.stereo.mode=off", "ingest.max_size=96") == 0
    view = IngestView(tmp_path / "rectified01" / "01_ingest")
    assert view.stereo_depth(view.indices[0]) is None and view.summary.stereo is None


def test_the_spread_term_is_zero_only_for_weight_at_the_measured_depth() -> None:
    """nerf.loss.stereo_spread: a ray whose weight sits at its measured depth costs nothing; a
    haze that averages to the same depth costs, and its gradient moves weight to the depth."""
    import torch

    from endopipe.stages.nerf.losses import depth_spread

    t = torch.linspace(5.0, 15.0, 11)[None]
    target = torch.tensor([10.0])
    sharp = torch.zeros(1, 11)
    sharp[0, 5] = 1.0  # all at t = 10
    assert float(depth_spread(t, sharp, target)) == 0.0
    haze = torch.full((1, 11), 1.0 / 11, requires_grad=True)  # expected depth 10 too
    cost = depth_spread(t, haze, target)
    assert float(cost.detach()) > 0.05
    cost.backward()
    grad = haze.grad[0]
    assert grad[5] == grad.min() and grad[0] > grad[3] > grad[5]  # cheapest at the depth
