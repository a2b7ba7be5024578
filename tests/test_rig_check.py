"""The rig check: a right eye whose frames lag the left's is paired anew, and the rows the
rectification leaves are found (stages/ingest/rig_check.py)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from endopipe.stages.ingest.rig_check import check_rig, row_disparities, shifted_rows

W, H = 320, 240
DISPARITY = 9.0  # px: a wall at one depth


def texture(seed: int = 0) -> np.ndarray:
    """A wall's texture: blobs at several scales (SIFT finds hundreds of features in it)."""
    rng = np.random.default_rng(seed)
    out = np.zeros((700, 900), np.float32)
    for sigma in (1.5, 4.0, 10.0):
        noise = rng.normal(size=out.shape).astype(np.float32)
        out += cv2.GaussianBlur(noise, (0, 0), sigma) * sigma
    out = (out - out.min()) / (out.max() - out.min()) * 255
    return cv2.cvtColor(out.astype(np.uint8), cv2.COLOR_GRAY2RGB)


def view(tex: np.ndarray, x: float, y: float) -> np.ndarray:
    """The W x H window of `tex` whose top-left corner is at (x, y), sub-pixel."""
    m = np.float32([[1, 0, -x], [0, 1, -y]])
    return cv2.warpAffine(tex, m, (W, H), flags=cv2.INTER_LINEAR)


#: Eight frames (the check's default: 16) and a pairing up to one frame off (2): the same
#: judgement at a third of the SIFT work.
QUICK = {"frames": 8, "max_offset": 1}


class Rig:
    """A camera panning over a wall, its vertical speed changing (up to 2.5 px a frame); the
    right eye sees the wall `DISPARITY` px to the left and `row` px higher."""

    def __init__(self, row: float = 0.0, lag: int = 0) -> None:
        self.tex, self.row, self.lag = texture(), row, lag

    def at(self, s: float) -> tuple[float, float]:
        return 200.0 + 3.0 * s, 200.0 + 12.0 * np.sin(s / 4.0)

    def left(self, s: int) -> np.ndarray:
        return view(self.tex, *self.at(s))

    def right(self, s: int) -> np.ndarray:
        x, y = self.at(s - self.lag)  # a lagging eye shows an earlier moment
        return view(self.tex, x + DISPARITY, y + self.row)


@pytest.mark.parametrize("lag", [0, 1, -1])
def test_the_pairing_of_the_same_moment_is_found(lag: int) -> None:
    rig = Rig(row=0.0, lag=lag)
    found = check_rig(list(range(5, 60)), rig.left, rig.right, **QUICK)
    assert found.frame_offset == lag, found.said
    assert found.spread_px is not None and found.spread_px < 0.1
    if lag:
        assert found.spread_as_named_px is not None and found.spread_as_named_px > 0.5
        assert "1 apart" in found.said
    assert found.row_shift_px == 0.0


def test_the_rectifications_rows_are_found_and_mended() -> None:
    rig = Rig(row=0.7)
    found = check_rig(list(range(5, 60)), rig.left, rig.right, **QUICK)
    assert found.frame_offset == 0
    assert found.row_shift_px == pytest.approx(0.7, abs=0.1)
    grey = [cv2.cvtColor(i, cv2.COLOR_RGB2GRAY) for i in (rig.left(20), rig.right(20))]
    mended = cv2.cvtColor(shifted_rows(rig.right(20), found.row_shift_px), cv2.COLOR_RGB2GRAY)
    assert abs(np.median(row_disparities(*grey))) == pytest.approx(0.7, abs=0.1)
    assert abs(np.median(row_disparities(grey[0], mended))) < 0.1


def test_a_right_eye_missing_frames_leaves_the_rig_unchecked_or_as_named() -> None:
    rig = Rig()
    found = check_rig(list(range(5, 60)), rig.left, lambda s: None, **QUICK)
    assert found.frame_offset == 0 and found.row_shift_px == 0.0
    assert "not checked" in found.said


def test_rows_no_rotation_mends_leave_the_rigs_depth_out() -> None:
    """A right eye whose rows wave by 3 px across the image (no rigid turn does that: a
    rectification gone wrong, a rolling shutter): its depth is left out with the reason."""
    from endopipe.stages.camera import Camera

    rig = Rig()
    xs = np.arange(W, dtype=np.float32)
    wave = np.broadcast_to(3.0 * np.sin(2 * np.pi * xs / W * 2), (H, W))
    map_x = np.broadcast_to(xs, (H, W)).astype(np.float32)
    map_y = (np.arange(H, dtype=np.float32)[:, None] + wave).astype(np.float32)

    def wavy(s: int) -> np.ndarray:
        return cv2.remap(rig.right(s), map_x, map_y, cv2.INTER_LINEAR)

    camera = Camera(width=W, height=H, fx=250.0, fy=250.0, cx=159.5, cy=119.5)
    found = check_rig(list(range(5, 60)), rig.left, wavy, camera=camera, **QUICK)
    assert found.refused is not None and "left out" in found.refused, found.said
    assert found.right_rotation is None
    # the same rig with its rows straight is used
    assert (
        check_rig(list(range(5, 60)), rig.left, rig.right, camera=camera, **QUICK).refused is None
    )


def _turned(image: np.ndarray, k: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """The image a camera turned by `rotation` (new-from-old) about its centre would see."""
    h = k @ rotation @ np.linalg.inv(k)
    return cv2.warpPerspective(image, h, (image.shape[1], image.shape[0]), flags=cv2.INTER_LINEAR)


def _stereo_abs_rel(case: Path) -> tuple[float, float]:
    """Median AbsRel of a finished ingest's stereo depth against the synthetic truth, and its
    coverage of the truth's pixels."""
    from endopipe.stages.ingest.view import IngestView
    from endopipe.stages.io.sources import open_input

    view = IngestView(case / "01_ingest")
    truth = open_input(Path(json.loads((case / "case.json").read_text())["input"])).ground_truth()
    errs, shares = [], []
    for i, entry in enumerate(view.file.frames):
        depth = view.stereo_depth(i)
        gt = truth.depth(entry.source_index)
        gt = cv2.resize(gt, depth.shape[::-1], interpolation=cv2.INTER_NEAREST)
        both = (depth > 0) & (gt > 0)
        errs.append(np.abs(depth[both] - gt[both]) / gt[both])
        shares.append(both.sum() / max((gt > 0).sum(), 1))
    return float(np.median(np.concatenate(errs))), float(np.mean(shares))


def test_a_rig_rotated_two_degrees_is_found_and_mended(tmp_path: Path) -> None:
    """A synthetic Hamlyn rig whose right eye is turned 2 degrees from what its calibration says
    (its images warped as that eye would see them): the check finds the matches off their rows,
    re-estimates the rotation from them, and the stereo depth is as good as with the true rig
    (within 10%); matched as the calibration says, it is far worse."""
    from endopipe.cli import main
    from endopipe.stages.camera import Camera

    src = tmp_path / "rectified01"
    args = ["synth", str(src), "--frames", "8", "--layout", "hamlyn", "--stereo", "--seed", "3"]
    assert main(args) == 0
    k_rows = (src / "intrinsics.txt").read_text().split()
    fx, cx, cy = float(k_rows[0]), float(k_rows[2]), float(k_rows[5])
    k = Camera(width=320, height=256, fx=fx, fy=fx, cx=cx, cy=cy).matrix()
    turned = tmp_path / "turned" / "rectified01"
    shutil.copytree(src, turned)
    axis = np.array([0.4, 0.3, 1.0]) / np.linalg.norm([0.4, 0.3, 1.0])
    rotation, _ = cv2.Rodrigues(axis * np.deg2rad(2.0))
    for f in sorted((turned / "image02").iterdir()):
        cv2.imwrite(str(f), _turned(cv2.imread(str(f)), np.asarray(k), rotation))

    def ingest(case_input: Path, work: Path, *extra: str) -> Path:
        run = ["run", str(case_input), "--workdir", str(work), "--until", "ingest", "--quiet"]
        assert main([*run, *extra]) == 0
        return work / case_input.name

    true_rig = _stereo_abs_rel(ingest(src, tmp_path / "w_true"))
    mended_case = ingest(turned, tmp_path / "w_mended")
    mended = _stereo_abs_rel(mended_case)
    as_said = _stereo_abs_rel(
        ingest(turned, tmp_path / "w_as_said", "--set", "ingest.stereo.check=false")
    )
    from endopipe.stages.ingest.view import IngestView

    rig = IngestView(mended_case / "01_ingest").summary.stereo_check
    assert "rotation re-estimated" in rig, rig
    assert mended[0] <= 1.1 * true_rig[0] + 0.002, (mended, true_rig)
    assert mended[1] >= 0.9 * true_rig[1], (mended, true_rig)
    assert as_said[0] > 2 * true_rig[0] or as_said[1] < 0.7 * true_rig[1], (as_said, true_rig)
