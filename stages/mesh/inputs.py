"""What the mesh stage reads upstream, as arrays: the registered frames' depth maps (through
05_depth's view) with their poses and colours, and the depth truncation they imply."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import TYPE_CHECKING

import numpy as np

from endopipe.pipeline.errors import StageFailed
from endopipe.stages.surface.tsdf import DepthFrame

if TYPE_CHECKING:
    from endopipe.stages.depth.view import DepthView
    from endopipe.stages.poses.view import PosesView


def valid_depth(depth: DepthView, index: int, min_opacity: float = 0.0) -> np.ndarray:
    """05_depth's z-depth of frame `index` as float32 with 0 wherever it is not to be trusted:
    non-finite or negative, or (when the opacity map exists) opacity under `min_opacity`."""
    d = depth.depth(index).astype(np.float32)
    d[~np.isfinite(d) | (d < 0)] = 0.0
    if min_opacity > 0:
        opacity = depth.opacity(index)
        if opacity is not None and opacity.shape == d.shape:
            d[opacity < min_opacity] = 0.0
    return d


def iter_depth_frames(
    depth: DepthView,
    poses: PosesView,
    min_opacity: float,
    image: Callable[[int], np.ndarray] | None = None,
    c2w: dict[int, np.ndarray] | None = None,
) -> Iterator[DepthFrame]:
    """The registered frames that have a depth map, with colour from `image(index)` (RGB,
    resized to the depth map's grid), at the poses `c2w` the depth maps were rendered at
    (NerfView.c2w; default: cameras.json's); frames `c2w` leaves out are skipped."""
    c2w = poses.c2w if c2w is None else c2w
    import cv2

    for i in poses.registered:
        if not depth.has_depth(i) or i not in c2w:
            continue
        d = valid_depth(depth, i, min_opacity)
        rgb = None
        if image is not None:
            rgb = image(i)
            if rgb.shape[:2] != d.shape:
                rgb = cv2.resize(rgb, d.shape[::-1], interpolation=cv2.INTER_AREA)
        yield DepthFrame(d, c2w[i], rgb)


def auto_depth_trunc(depths: Iterable[np.ndarray], percentile: float) -> float:
    """The `percentile` percentile of all valid (> 0) depth values (subsampled)."""
    vals = [d[d > 0][::7] for d in depths]
    vals = [v for v in vals if len(v)]
    if not vals:
        raise StageFailed("mesh: the depth maps have no valid pixel")
    return float(np.percentile(np.concatenate(vals), percentile))


def depth_trunc(
    depth: DepthView, poses: PosesView, fixed: float | None, percentile: float, min_opacity: float
) -> float:
    """`fixed` when given, else the `percentile` percentile of the registered frames' valid
    depths (`valid_depth` with `min_opacity`)."""
    if fixed is not None:
        return fixed
    frames = iter_depth_frames(depth, poses, min_opacity)
    return auto_depth_trunc((f.depth for f in frames), percentile)
