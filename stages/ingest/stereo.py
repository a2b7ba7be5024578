"""Metric depth from a rectified stereo pair: semi-global matching (OpenCV's StereoSGBM) with a
left-right consistency check.

Why here: a right view fixes what one camera cannot, the scale. The pair is rectified (the
right camera is the left one moved by the baseline along +x, same intrinsics), so a left pixel
at x sees its point at x - d in the right image and z = fx * baseline / d. Disparity is in
pixels of the images matched: `match_depth` takes the pair at the working size with fx at that
size, and the depth, in mm, needs no rescaling.

Pixels the matcher cannot vouch for stay unknown (0): no match, a match not unique, one the
right-to-left match disagrees with by more than `lr_max_diff_px` (occlusions, repeated
texture), small speckles, and the left strip that the right camera does not see.
"""

from __future__ import annotations

import cv2
import numpy as np

from endopipe.stages.ingest.config import StereoConfig

#: StereoSGBM's disparities are fixed point with 4 fractional bits.
SUBPIXEL = 16.0
#: ingest.stereo.matcher_mode -> StereoSGBM's mode.
MODES = {
    "hh": cv2.STEREO_SGBM_MODE_HH,
    "hh4": cv2.STEREO_SGBM_MODE_HH4,
    "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
}
#: Fewer tracked corners than this do not say how near the scene is: the widest search is used.
MIN_CORNERS = 20


def disparity_range(
    left: np.ndarray, right: np.ndarray, fx: float, baseline_mm: float, cfg: StereoConfig
) -> int:
    """numDisparities, a multiple of 16: what the pair's own corners need (their largest
    disparity, tracked left to right, with a margin), never more than the nearest depth asked
    for (`min_depth_mm`) or half the width. A wider search than the scene needs only finds more
    false matches, and loses the left strip it cannot search."""
    width = left.shape[1]
    nearest = fx * baseline_mm / cfg.min_depth_mm
    cap = max(16, min(width // 2, int(nearest)) // 16 * 16)
    seen = corner_disparities(left, right)
    if seen.size < MIN_CORNERS:
        return cap
    wanted = np.percentile(seen, 99) * 1.25 + 8
    return int(min(cap, max(16, np.ceil(wanted / 16.0) * 16)))


def corner_disparities(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Disparities (px) of the left image's corners tracked into the right image (pyramidal
    Lucas-Kanade) that stay on their row and track back to where they started."""
    corners = cv2.goodFeaturesToTrack(left, 400, 0.01, 5)
    if corners is None:
        return np.zeros(0)
    lk = {"winSize": (21, 21), "maxLevel": 4}
    there, ok, _ = cv2.calcOpticalFlowPyrLK(left, right, corners, None, **lk)
    back, ok_back, _ = cv2.calcOpticalFlowPyrLK(right, left, there, None, **lk)
    a, b, c = corners[:, 0], there[:, 0], back[:, 0]
    good = (ok[:, 0] == 1) & (ok_back[:, 0] == 1)
    good &= (np.abs(a - c).max(axis=1) < 0.5) & (np.abs(a[:, 1] - b[:, 1]) < 1.0)
    disparity = a[good, 0] - b[good, 0]
    return disparity[disparity > 0]


def matcher(num_disparities: int, cfg: StereoConfig) -> cv2.StereoSGBM:
    """StereoSGBM on grey images (`matcher_mode`); P1 / P2 as OpenCV's sample (8 and 32 x block
    area)."""
    block = cfg.block_size
    return cv2.StereoSGBM.create(
        minDisparity=0,
        numDisparities=num_disparities,
        blockSize=block,
        P1=8 * block * block,
        P2=32 * block * block,
        disp12MaxDiff=-1,  # the check below is done on both full disparity maps instead
        uniquenessRatio=cfg.uniqueness,
        speckleWindowSize=cfg.speckle_window,
        speckleRange=cfg.speckle_range,
        preFilterCap=63,
        mode=MODES[cfg.matcher_mode],
    )


def grey(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)


def disparities(left: np.ndarray, right: np.ndarray, sgbm: cv2.StereoSGBM, pad: int) -> tuple:
    """(left-to-right, right-to-left) disparity maps in pixels (NaN: no match). The right one
    is matched on the mirrored pair, in which the right image plays the left's part. Both are
    padded by `pad` px where the search would leave the image (StereoSGBM gives nothing within
    its range of the left edge), so pixels near it whose match is in view keep theirs."""
    a = padded_match(sgbm, left, right, pad)
    b = padded_match(sgbm, right[:, ::-1], left[:, ::-1], pad)[:, ::-1]
    a[a <= 0] = np.nan
    b[b <= 0] = np.nan
    return a, b


def padded_match(sgbm: cv2.StereoSGBM, left: np.ndarray, right: np.ndarray, pad: int) -> np.ndarray:
    """StereoSGBM's disparity (px) of `left`, the pair padded on the left by its edge pixels."""
    wide = [cv2.copyMakeBorder(im, 0, 0, pad, 0, cv2.BORDER_REPLICATE) for im in (left, right)]
    return sgbm.compute(*wide)[:, pad:].astype(np.float32) / SUBPIXEL


def consistent(left_disp: np.ndarray, right_disp: np.ndarray, max_diff: float) -> np.ndarray:
    """Where the right image's match of a left pixel's match points back at it."""
    h, w = left_disp.shape
    xs = np.arange(w, dtype=np.float32)[None, :]
    with np.errstate(invalid="ignore"):
        xr = np.rint(xs - left_disp)
        inside = (xr >= 0) & (xr < w)
    back = np.full_like(left_disp, np.nan)
    rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
    back[inside] = right_disp[rows[inside], xr[inside].astype(np.int64)]
    with np.errstate(invalid="ignore"):
        return inside & (np.abs(left_disp - back) <= max_diff)


def match_depth(
    left: np.ndarray,
    right: np.ndarray,
    fx: float,
    baseline_mm: float,
    cfg: StereoConfig,
    usable: np.ndarray | None = None,
) -> np.ndarray:
    """float32 z-depth (mm, 0 = unknown) of the left image from a rectified pair (HxWx3 uint8
    RGB of one size), with `fx` in pixels of these images; only where `usable` (the field of
    view) is nonzero, when given."""
    if left.shape != right.shape:
        raise ValueError(f"stereo pair of two sizes: {left.shape} and {right.shape}")
    left, right = grey(left), grey(right)
    n = disparity_range(left, right, fx, baseline_mm, cfg)
    a, b = disparities(left, right, matcher(n, cfg), n)
    keep = consistent(a, b, cfg.lr_max_diff_px) & (a >= cfg.min_disparity_px)
    if usable is not None:
        keep &= usable > 0
    depth = np.zeros(a.shape, np.float32)
    depth[keep] = fx * baseline_mm / a[keep]
    return depth
