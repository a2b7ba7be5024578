"""The metric scale of SfM poses from a stereo rig's depth: SfM leaves the scale free, and a
rectified pair measures it at every matched pixel.

Why the SfM points: each is a pixel whose depth SfM triangulated in its own units; the stereo
depth at the same pixel is millimetres, so their ratio is the scale. The median over every
observation ignores the matcher's failures (occlusion edges, specular spots) and SfM's
outliers; the spread of the ratios says how far one scale explains them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from endopipe.stages.poses.summary import StereoScale

if TYPE_CHECKING:
    from endopipe.stages.poses.view import SparseObservations

#: Fewer matched observations than this: no scale (a median of a handful is a guess).
MIN_POINTS = 30


def stereo_scale(
    obs: SparseObservations | None,
    c2w: dict[int, np.ndarray],
    stereo_depth: Callable[[int], np.ndarray | None],
    size: tuple[int, int],
) -> StereoScale | None:
    """The scale that maps the SfM depth of the observations (`size` = (H, W) of their pixel
    grid, the stereo maps' too) onto the stereo depth; None with fewer than MIN_POINTS."""
    if obs is None or not len(obs.frame):
        return None
    h, w = size
    ratios: list[np.ndarray] = []
    for f in np.unique(obs.frame):
        depth = stereo_depth(int(f))
        if depth is None or int(f) not in c2w:
            continue
        sel = obs.frame == f
        w2c = np.linalg.inv(c2w[int(f)])
        z_sfm = obs.xyz[sel] @ w2c[2, :3] + w2c[2, 3]
        col = np.round(obs.uv[sel, 0]).astype(np.int64)
        row = np.round(obs.uv[sel, 1]).astype(np.int64)
        inside = (col >= 0) & (col < w) & (row >= 0) & (row < h) & (z_sfm > 0)
        z_mm = np.zeros(len(z_sfm))
        z_mm[inside] = depth[row[inside], col[inside]]
        good = inside & (z_mm > 0)
        ratios.append(z_mm[good] / z_sfm[good])
    r = np.concatenate(ratios) if ratios else np.zeros(0)
    if len(r) < MIN_POINTS:
        return None
    scale = float(np.median(r))
    return StereoScale(
        mm_per_unit=scale, points=len(r), spread=float(np.median(np.abs(r / scale - 1.0)))
    )
