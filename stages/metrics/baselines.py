"""Guesses that look at no geometry, scored beside ours so a number has a floor: two of depth,
and one of a held-out frame's colour (its neighbours' average).

A reconstruction that does not beat these has not reconstructed the scene; it has only
rediscovered what every endoscopic frame looks like. Plain functions over arrays, no I/O;
each returns a z-depth map that is positive everywhere (the scoring protocols remove the
unknown scale, and for a relative ground truth the shift as well).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import cv2
import numpy as np

from endopipe.stages.metrics.exposure import exposure_matched

#: The names the guesses are stored under in metrics.json (`baselines`), in display order.
GUESSES = ("radial", "brightness")

#: Gaussian blur of the brightness guess, as a fraction of the image diagonal: wide enough to
#: wash out texture and specular speckle, narrow enough to keep the shading of folds.
BLUR_OF_DIAGONAL = 0.01
#: Added to the blurred grey level so black pixels give a large but finite depth.
BRIGHTNESS_FLOOR = 1e-3


def radial_guess(
    height: int, width: int, cx: float, cy: float, inside: np.ndarray | None = None
) -> np.ndarray:
    """ "The image centre is far": depth = r_max - r + 1, with r the pixel distance to the
    principal point (pixel-centre convention) and r_max the largest r inside the field of view
    (`inside`, the whole image when None); clamped to 1 beyond r_max, outside the field of
    view. Looks at no pixel's value."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    r = np.hypot(u - cx, v - cy)
    r_max = float(r[inside.astype(bool)].max()) if inside is not None and inside.any() else r.max()
    return np.maximum(r_max - r + 1.0, 1.0).astype(np.float32)


def brightness_guess(rgb: np.ndarray, blur_of_diagonal: float = BLUR_OF_DIAGONAL) -> np.ndarray:
    """Inverse-square shading (a light at the camera: I ~ 1/z², so z ~ 1/sqrt(I)): depth =
    1/sqrt(blurred grey + BRIGHTNESS_FLOOR), grey the mean of the RGB channels in 0..1 (uint8
    images are divided by 255), blurred with a Gaussian of sigma = `blur_of_diagonal` times
    the image diagonal."""
    img = np.asarray(rgb)
    grey = img.astype(np.float32).mean(axis=-1) if img.ndim == 3 else img.astype(np.float32)
    if np.issubdtype(img.dtype, np.integer):
        grey /= 255.0
    sigma = blur_of_diagonal * float(np.hypot(*grey.shape[:2]))
    blurred = cv2.GaussianBlur(grey, (0, 0), sigmaX=sigma) if sigma > 0 else grey
    return (1.0 / np.sqrt(np.clip(blurred, 0.0, None) + BRIGHTNESS_FLOOR)).astype(np.float32)


def neighbour_frames(held: int, order: list[int], skip: set[int]) -> list[int]:
    """The frames a held-out frame's neighbour average takes: the nearest frame before and the
    nearest after it in `order` (the input's frame order) that are not in `skip` (the held-out
    ones), or the one there is at an end."""
    pos = order.index(held)
    before = next((i for i in reversed(order[:pos]) if i not in skip), None)
    after = next((i for i in order[pos + 1 :] if i not in skip), None)
    return [i for i in (before, after) if i is not None]


def neighbour_average(images: list[np.ndarray]) -> np.ndarray:
    """A held-out frame predicted by averaging its neighbours (the deformable-scene field's
    floor: on a still camera it is hard to beat, and it knows nothing of the scene's shape)."""
    return np.mean(np.stack([np.asarray(x, np.float32) for x in images]), axis=0)


def neighbour_guesses(
    image: Callable[[int], np.ndarray],
    scored: Callable[[int], np.ndarray],
    order: list[int],
    held: list[int],
    skip: set[int],
    fit_exposure: bool = False,
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(frame, its neighbour average, its scored pixels) for each held-out frame with a trained
    neighbour (`neighbour_frames`); `image(i)` a frame in [0, 1], `scored(i)` its pixels to
    score. With `fit_exposure` the guess's exposure is fitted to the frame as a field's render's
    is (metrics/exposure.py)."""
    for i in held:
        near = neighbour_frames(i, order, skip)
        if not near:
            continue
        frame, pixels = image(i), scored(i)
        guess = neighbour_average([image(j) for j in near])
        if fit_exposure:
            guess = exposure_matched(guess, frame, pixels)[0]
        yield frame, guess, pixels
