"""A held-out frame's exposure, fitted to the frame before its render is scored.

Why: a scope's exposure and white balance are the camera's, not the scene's. A field that
learns one exposure a training frame knows a held-out frame's only by interpolating its
neighbours', which fails where the exposure jumps or where no neighbour lies on one side (the
clip's first frame). Scoring the render with that guess measures the guess, not the field.
NeRF-W's protocol fits the held-out frame's appearance to the left half of the frame; here it
is three gains (one a colour channel, what the field's exposure is), fitted by least squares to
the left half of the scored pixels and applied to the whole image. The neighbour average, the
baseline scored beside it, gets the same fit.
"""

from __future__ import annotations

import numpy as np


def exposure_matched(
    rgb: np.ndarray, frame: np.ndarray, scored: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """`rgb` (H, W, 3, in [0, 1]) times the gain a channel that best fits `frame` on the left
    half of the `scored` pixels (columns left of the image's middle), clipped to [0, 1]; and the
    three gains (ones when that half holds no scored pixel)."""
    left = scored.astype(bool).copy()
    left[:, left.shape[1] // 2 :] = False
    gains = np.ones(3, np.float32)
    if left.any():
        r = rgb[left].astype(np.float64)
        f = frame[left].astype(np.float64)
        power = (r * r).sum(0)
        gains = np.where(power > 0, (r * f).sum(0) / np.maximum(power, 1e-12), 1.0)
        gains = gains.astype(np.float32)
    return np.clip(rgb * gains, 0.0, 1.0).astype(np.float32), gains
