"""Depth from the light's fall-off, for a camera that stands still with nothing else to place
depth: no parallax, no stereo, no depth maps given.

Why: the scope's light sits at the camera, so the linear light a pixel receives falls off as
1/r² with the distance r along its ray (the field's own shading model, nerf.shading). Blurred
wide enough to wash out the tissue's texture, the frame's linear brightness gives the range as
1/sqrt(I) up to one unknown factor: a relative depth map, made per frame from that frame alone.
It ignores the surface's tilt (a still camera does not see it: the field's shading drops n.l
there too) and the albedo's slow changes, so it only shapes each frame's depth through the
scale-and-shift-invariant prior loss (losses.prior_depth), as a user's `--depth-prior` does.
"""

from __future__ import annotations

import cv2
import numpy as np

#: Gaussian blur of the linear brightness, as a fraction of the image diagonal: wide enough to
#: wash out the texture (a cavity wall's vessels and speckle), narrow enough to keep a fold.
BLUR_OF_DIAGONAL = 0.03
#: A pixel whose blur footprint is less than this share usable (tools, highlights, the scope's
#: black surround) gets no shading depth: its neighbourhood's light is not the tissue's.
MIN_USABLE_SHARE = 0.5
#: Linear brightness at or below this is no measurement of the light (black, clipped noise).
MIN_LINEAR = 1e-4


def only_shading_places_depth(ingest, poses) -> bool:
    """A camera that stands still with no stereo, no depth given and no `--depth-prior`
    (IngestView, PosesView): the one case the depth from shading is for, in the field's
    training (an option) and beside its scores."""
    return bool(poses.still) and not ingest.has_stereo and not ingest.has_depth_prior


def shading_depth(
    rgb: np.ndarray, usable: np.ndarray, directions: np.ndarray, gamma: float
) -> np.ndarray:
    """float32 (H, W) relative z-depth of one frame (0 = unknown): 1/sqrt(I) along each ray,
    I the frame's linear grey (display-decoded with `gamma`) averaged over the `usable` (bool)
    pixels of a Gaussian footprint. `directions` are the camera-frame rays (H, W, 3) with z = 1
    (camera.rays.image_directions), so z-depth = range / |direction|."""
    grey = np.asarray(rgb, dtype=np.float32).mean(axis=-1) / 255.0
    linear = np.power(grey, gamma, dtype=np.float32)
    weight = usable.astype(np.float32)
    sigma = BLUR_OF_DIAGONAL * float(np.hypot(*grey.shape))
    light = cv2.GaussianBlur(linear * weight, (0, 0), sigmaX=sigma)
    share = cv2.GaussianBlur(weight, (0, 0), sigmaX=sigma)
    known = usable & (share >= MIN_USABLE_SHARE)
    mean_light = np.where(known, light / np.maximum(share, 1e-6), 0.0)
    known &= mean_light > MIN_LINEAR
    ray_length = np.linalg.norm(directions, axis=-1)
    depth = np.zeros(grey.shape, np.float32)
    depth[known] = 1.0 / (np.sqrt(mean_light[known]) * ray_length[known])
    return depth
