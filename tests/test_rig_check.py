"""The rig check: a right eye whose frames lag the left's is paired anew, and the rows the
rectification leaves are found (stages/ingest/rig_check.py)."""

from __future__ import annotations

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
    found = check_rig(list(range(5, 60)), rig.left, rig.right)
    assert found.frame_offset == lag, found.said
    assert found.spread_px is not None and found.spread_px < 0.1
    if lag:
        assert found.spread_as_named_px is not None and found.spread_as_named_px > 0.5
        assert "1 apart" in found.said
    assert found.row_shift_px == 0.0


def test_the_rectifications_rows_are_found_and_mended() -> None:
    rig = Rig(row=0.7)
    found = check_rig(list(range(5, 60)), rig.left, rig.right)
    assert found.frame_offset == 0
    assert found.row_shift_px == pytest.approx(0.7, abs=0.1)
    grey = [cv2.cvtColor(i, cv2.COLOR_RGB2GRAY) for i in (rig.left(20), rig.right(20))]
    mended = cv2.cvtColor(shifted_rows(rig.right(20), found.row_shift_px), cv2.COLOR_RGB2GRAY)
    assert abs(np.median(row_disparities(*grey))) == pytest.approx(0.7, abs=0.1)
    assert abs(np.median(row_disparities(grey[0], mended))) < 0.1


def test_a_right_eye_missing_frames_leaves_the_rig_unchecked_or_as_named() -> None:
    rig = Rig()
    found = check_rig(list(range(5, 60)), rig.left, lambda s: None)
    assert found.frame_offset == 0 and found.row_shift_px == 0.0
    assert "not checked" in found.said
