"""The SfM points' depth refined by multi-view patch correlation before the field follows it.

Why: the depth term pins the field's scale to the SfM points, and their depth is noisy: on the
bench colon 28% of the tracked pixels are over 5% off the truth, as many short as long, most of
them seen under a narrow angle (a keypoint is placed to about a pixel, and a narrow angle turns
that into a long error along the ray). Each point is moved along the ray of a reference view to
the depth where a small patch around it looks most alike in the frames near its track, sampled
through a plane facing that view. More views than the track and a whole patch instead of one
keypoint narrow the error (bench colon: 28% -> 21% of the tracked pixels over 5% off).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.ndimage import map_coordinates

from endopipe.stages.camera.model import Camera
from endopipe.stages.camera.projection import project_camera, world_to_camera
from endopipe.stages.camera.rays import pixel_directions
from endopipe.stages.poses.view import SparseObservations

#: Depths tried along the reference ray, as a fraction of the SfM point's: 1 +- SPAN.
SPAN = 0.15
STEPS = 61
#: Patch half-size (px): 7x7.
HALF = 3
#: A point moves only where the patches correlate at least this well on average.
MIN_NCC = 0.7
#: Frames compared beyond either end of a point's track.
EXTEND = 10


def refine_points(
    obs: SparseObservations,
    camera: Camera,
    c2w: dict[int, np.ndarray],
    grey: Mapping[int, np.ndarray],
    extend: int = EXTEND,
) -> tuple[SparseObservations, np.ndarray]:
    """(observations with the refined points and their pixels re-projected, which observations
    moved), the frames compared being those of `c2w`. `grey[frame]`: the frame as a float image
    in [0, 1]; `extend`: frames beyond either end of a point's track that are compared too. A
    point without a clear best depth stays as SfM put it."""
    points, which = np.unique(obs.xyz, axis=0, return_inverse=True)
    which = which.ravel()
    frames = np.array(sorted(c2w))
    grid = np.arange(-HALF, HALF + 1, dtype=np.float64)
    offsets = np.stack(np.meshgrid(grid, grid), -1).reshape(-1, 2)
    scales = np.linspace(1.0 - SPAN, 1.0 + SPAN, STEPS)
    refined = points.copy()
    moved = np.zeros(len(points), bool)
    order = np.argsort(which, kind="stable")
    starts = np.searchsorted(which[order], np.arange(len(points) + 1))
    for p in range(len(points)):
        track = [int(f) for f in obs.frame[order[starts[p] : starts[p + 1]]] if int(f) in c2w]
        if len(track) < 2:
            continue
        track.sort()
        ref = track[len(track) // 2]
        near = frames[(frames >= track[0] - extend) & (frames <= track[-1] + extend)]
        x_ref = world_to_camera(points[p][None], c2w[ref])[0]
        factor = best_depth(x_ref, ref, near, camera, c2w, grey, offsets, scales)
        if factor is not None:  # along the ray: the same pixel in the reference frame
            refined[p] = c2w[ref][:3, :3] @ (x_ref * factor) + c2w[ref][:3, 3]
            moved[p] = True
    xyz = refined[which]
    uv = obs.uv.copy()
    for f in np.unique(obs.frame):
        sel = obs.frame == f
        if int(f) in c2w:
            uv[sel] = project_camera(camera, world_to_camera(xyz[sel], c2w[int(f)]))[0]
    out = SparseObservations(obs.frame, uv, xyz, obs.track, obs.error, obs.angle)
    return out, moved[which]


def best_depth(
    x_ref: np.ndarray,
    ref: int,
    frames: np.ndarray,
    camera: Camera,
    c2w: dict[int, np.ndarray],
    image: Mapping[int, np.ndarray],
    offsets: np.ndarray,
    scales: np.ndarray,
) -> float | None:
    """The factor on the depth of the point `x_ref` (in the frame `ref`) where the patches
    correlate best (sub-step by a parabola), or None: no other frame sees the whole patch, too
    little texture, a weak or edge-of-range peak."""
    if x_ref[2] <= 0:
        return None
    uv0 = project_camera(camera, x_ref[None])[0][0]
    pix = uv0 + offsets
    h, w = image[ref].shape
    if pix.min() < 0 or pix[:, 0].max() > w - 1 or pix[:, 1].max() > h - 1:
        return None
    patch = sample(image[ref], pix)
    patch = patch - patch.mean()
    norm = float(np.linalg.norm(patch))
    if norm < 1e-4 * np.sqrt(len(patch)):  # a flat patch (grey in [0, 1]) correlates with noise
        return None
    dirs = pixel_directions(camera, pix[:, 0], pix[:, 1])  # z = 1
    if not np.isfinite(dirs).all():  # a pixel the lens model does not reach
        return None
    on_plane = dirs[None] * (x_ref[2] * scales)[:, None, None]  # (S, P, 3) reference frame
    world = on_plane @ c2w[ref][:3, :3].T + c2w[ref][:3, 3]
    score, views = np.zeros(len(scales)), 0
    for f in frames:
        if f == ref:
            continue
        uv, z = project_camera(camera, world_to_camera(world.reshape(-1, 3), c2w[int(f)]))
        inside = np.isfinite(uv).all() and uv.min() >= 0
        if not inside or (z <= 0).any() or uv[:, 0].max() > w - 1 or uv[:, 1].max() > h - 1:
            continue
        vals = sample(image[int(f)], uv).reshape(len(scales), -1)
        vals = vals - vals.mean(1, keepdims=True)
        score += (vals @ patch) / (np.linalg.norm(vals, axis=1) * norm + 1e-9)
        views += 1
    if views == 0:
        return None
    score /= views
    i = int(np.argmax(score))
    if score[i] < MIN_NCC or i == 0 or i == len(scales) - 1:
        return None
    a, b, c = score[i - 1], score[i], score[i + 1]
    curve = a - 2.0 * b + c
    step = 0.5 * (a - c) / curve if curve < 0 else 0.0
    return float(np.interp(i + step, np.arange(len(scales)), scales))


def sample(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of a (H, W) image at pixel coordinates (N, 2), OpenCV convention."""
    return map_coordinates(img, [uv[:, 1], uv[:, 0]], order=1, mode="nearest")
