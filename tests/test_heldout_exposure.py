"""A held-out frame's exposure fitted to the frame before its render is scored
(stages/metrics/exposure.py): the camera's gain is taken out, the scene's error is not, and the
neighbour average is fitted alike."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np

from endopipe.stages.depth.evaluate import evaluate
from endopipe.stages.metrics.exposure import exposure_matched

H, W = 48, 64
GAINS = np.array([0.62, 0.65, 0.68], np.float32)  # the sinus's first frame against its render


def textured(seed: int = 0) -> np.ndarray:
    """A smooth random RGB texture in [0.1, 0.9]."""
    noise = np.random.default_rng(seed).random((H // 8, W // 8, 3)).astype(np.float32)
    return 0.1 + 0.8 * cv2.resize(noise, (W, H), interpolation=cv2.INTER_CUBIC).clip(0, 1)


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    return float(-10 * np.log10(((a - b) ** 2).mean(-1)[mask].mean() + 1e-20))


def test_a_render_at_another_exposure_is_matched_back_to_the_frame() -> None:
    frame = textured() * GAINS  # the frame darker than the render, a gain a channel
    render = textured()
    every = np.ones((H, W), bool)
    matched, gains = exposure_matched(render, frame, every)
    np.testing.assert_allclose(gains, GAINS, atol=1e-5)
    assert psnr(matched, frame, every) > 80 and psnr(render, frame, every) < 20


def test_the_gains_come_from_the_left_half_and_the_scene_error_stays() -> None:
    frame = textured() * GAINS
    render = textured()
    wrong = render.copy()
    wrong[:, W // 2 :] = textured(seed=1)[:, W // 2 :]  # the right half: another scene
    every = np.ones((H, W), bool)
    matched, gains = exposure_matched(wrong, frame, every)
    np.testing.assert_allclose(gains, GAINS, atol=1e-5)  # fitted where the render is right
    right = every.copy()
    right[:, : W // 2] = False
    assert psnr(matched, frame, right) < 25  # the wrong half is scored as wrong


@dataclass
class Frames:
    """What the depth stage's evaluation reads of the ingest view for held-out frames."""

    images: dict[int, np.ndarray]

    @property
    def frames(self) -> list:
        return [SimpleNamespace(index=i) for i in sorted(self.images)]

    def image(self, i: int) -> np.ndarray:
        return self.images[i]

    def mask(self, i: int) -> np.ndarray:
        return np.full((H, W), 255, np.uint8)


def test_the_depth_stage_scores_the_render_and_the_neighbours_each_exposure_fitted() -> None:
    """Three frames of one scene, the middle one held out and darker (the scope's exposure
    dropped): a render of the scene at the neighbours' exposure, fitted, is the frame; the
    neighbour average is fitted alike, so both gain and the comparison stays fair."""
    scene = textured()
    frames = {0: scene, 1: scene * GAINS, 2: scene}
    ingest = Frames({i: (255 * f).round().astype(np.uint8) for i, f in frames.items()})
    as_is = evaluate(None, ingest, {}, {}, {1: scene})
    fitted = evaluate(None, ingest, {}, {}, {1: scene}, fit_exposure=True)
    assert as_is["heldout_psnr"] < 15 and fitted["heldout_psnr"] > 45
    assert as_is["neighbour_average"]["psnr"] < 15 < 45 < fitted["neighbour_average"]["psnr"]


def test_a_real_scopes_exposure_drift_is_what_the_fit_takes_out(shared_data: Path) -> None:
    """The real sinus recording's first frames: the scope's auto-exposure darkens the image
    while the view barely moves. Frame 3 guessed for frame 0 was measured 15.66 dB as it is,
    19.19 fitted (gains 0.81 / 0.79 / 0.78): the fit takes out the drift, not the motion."""
    folder = shared_data / "jhu_sinus_381"
    inside = cv2.imread(str(folder / "mask.png"), cv2.IMREAD_GRAYSCALE) > 127

    def frame(i: int) -> np.ndarray:
        bgr = cv2.imread(str(folder / "frames" / f"{i:06d}.jpg"))
        return bgr[..., ::-1].astype(np.float32) / 255.0

    first, later = frame(0), frame(3)
    matched, gains = exposure_matched(later, first, inside)
    assert (gains < 0.85).all() and (gains > 0.7).all(), gains
    gain_db = psnr(matched, first, inside) - psnr(later, first, inside)
    assert 2.5 < gain_db < 5.0, gain_db  # 3.5 measured; the rest is the motion
