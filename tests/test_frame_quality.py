"""Blur and near-duplicate cues, on real C3VD colonoscope frames and synthetic ones."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from endopipe.stages.ingest.frame_quality import (
    QualityConfig,
    frame_difference,
    is_blurred,
    sharpness,
)
from endopipe.stages.ingest.masks import FovConfig, fov_mask_for_sequence

C3VD = Path("/work/shared/data/c3vd_v3_preview/rgb")


@pytest.fixture(scope="module")
def c3vd() -> tuple[list[np.ndarray], np.ndarray]:
    files = sorted(C3VD.glob("*.png"))
    if not files:
        pytest.skip(f"no data in {C3VD}")
    frames = [cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB) for p in files]
    fov, _ = fov_mask_for_sequence(frames, FovConfig())
    return frames, fov


def test_blurred_copy_is_much_less_sharp(c3vd):
    frames, fov = c3vd
    scores = [sharpness(f, fov) for f in frames]
    cfg = QualityConfig()
    assert not any(is_blurred(s, scores, cfg.blur_rel_threshold) for s in scores)
    for sigma in (1.5, 3.0):
        blurred = cv2.GaussianBlur(frames[0], (0, 0), sigma)
        score = sharpness(blurred, fov)
        assert score < 0.2 * scores[0], f"sigma {sigma}: {score:.1f} vs {scores[0]:.1f}"
        assert is_blurred(score, scores, cfg.blur_rel_threshold)
    assert sharpness(cv2.cvtColor(frames[0], cv2.COLOR_RGB2GRAY), fov) == pytest.approx(
        scores[0], rel=1e-4
    )


def test_sharpness_ignores_the_mask_edge():
    """A flat image inside a black border: its only detail is the border's edge."""
    img = np.full((120, 160, 3), (180, 90, 80), np.uint8)
    img[:, :30] = 0
    mask = np.zeros(img.shape[:2], np.uint8)
    mask[:, 30:] = 255
    assert sharpness(img) > 10
    assert sharpness(img, mask) < 1e-6
    assert sharpness(img, np.zeros_like(mask)) == 0.0


def test_is_blurred_is_relative_to_the_sequence():
    assert is_blurred(10.0, [100.0, 120.0, 90.0], 0.4)
    assert not is_blurred(60.0, [100.0, 120.0, 90.0], 0.4)
    assert not is_blurred(6.0, [10.0, 12.0, 9.0], 0.4)  # same ratio, another scale
    assert not is_blurred(1.0, [], 0.4)


def test_frame_difference_separates_duplicates_from_motion(c3vd):
    frames, fov = c3vd
    a = frames[0]
    threshold = QualityConfig().duplicate_threshold
    assert frame_difference(a, a.copy(), fov) < 1e-9
    ok, buf = cv2.imencode(".jpg", a, [cv2.IMWRITE_JPEG_QUALITY, 85])
    assert ok
    recoded = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    assert frame_difference(a, recoded, fov) < threshold  # the same frame, re-encoded
    shifted = np.roll(a, 6, axis=1)
    diff = frame_difference(a, shifted, fov)
    assert diff > 5 * threshold
    assert 0.0 <= diff <= 1.0
    assert frame_difference(a, frames[40], fov) > threshold
    assert frame_difference(np.zeros_like(a), np.full_like(a, 255)) == pytest.approx(1.0)
    with pytest.raises(ValueError):
        frame_difference(a, a[:-1])
