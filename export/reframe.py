"""One pinhole camera re-framed for a loader that assumes one focal length, a principal point at
a fixed place and maybe a fixed size: the frames are resampled (one scale per axis, so fx = fy)
and cropped about the principal point, and the depth and masks with them.

The crop keeps the largest window the target's shape allows around the principal point, so no
output pixel is made up (no padding); where that keeps less than `MIN_KEPT` of the frame (the
principal point far off the centre, or a very different shape) it is refused in one line.
The mapping is one affine map of pixel centres, u' = s_x (u - c_x) + c'_x, applied by OpenCV;
depth is resampled only from valid samples (0 = unknown stays unknown, never averaged in).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera

#: The least share of the frame's area a re-framing may keep.
MIN_KEPT = 0.5
#: A resampled pixel counts as valid when this much of its interpolation weight was valid.
VALID_WEIGHT = 0.999


@dataclass(frozen=True)
class Reframe:
    """The affine map from the frames' pixels to the target's, and the target's camera."""

    sx: float
    sy: float
    tx: float
    ty: float
    camera: Camera  # pinhole, fx == fy, at the target's size and principal point
    kept: float  # the share of the frame's area inside the target

    @property
    def identity(self) -> bool:
        return (
            abs(self.sx - 1) < 1e-9
            and abs(self.sy - 1) < 1e-9
            and abs(self.tx) < 1e-9
            and abs(self.ty) < 1e-9
        )

    def image(self, rgb: np.ndarray) -> np.ndarray:
        if self.identity:
            return rgb
        return _warp(rgb, self, cv2.INTER_LINEAR)

    def mask(self, usable: np.ndarray) -> np.ndarray:
        """bool usable mask: a target pixel is usable when all it was made from was."""
        if self.identity:
            return usable
        return _warp(usable.astype(np.float32), self, cv2.INTER_LINEAR) >= VALID_WEIGHT

    def depth(self, depth: np.ndarray) -> np.ndarray:
        """z-depth (unchanged by a pinhole's re-framing: only the pixel grid moves)."""
        if self.identity:
            return depth
        valid = (np.isfinite(depth) & (depth > 0)).astype(np.float32)
        d = np.where(valid > 0, depth, 0).astype(np.float32)
        num = _warp(d, self, cv2.INTER_LINEAR)
        den = _warp(valid, self, cv2.INTER_LINEAR)
        return np.where(den >= VALID_WEIGHT, num / np.maximum(den, 1e-6), 0).astype(np.float32)


def reframe(
    k: Camera, size: tuple[int, int] | None, principal: tuple[float, float] | None = None
) -> Reframe:
    """Map pinhole camera `k` onto a `size` (width, height; None: k's own) image with one focal
    length and its principal point at `principal` (default: the image's centre)."""
    w, h = size if size is not None else (k.width, k.height)
    pcx, pcy = principal if principal is not None else ((w - 1) / 2, (h - 1) / 2)
    # Tangents of the half-angles the frame reaches on each side of its principal point.
    left, right = (k.cx + 0.5) / k.fx, (k.width - 0.5 - k.cx) / k.fx
    top, bottom = (k.cy + 0.5) / k.fy, (k.height - 0.5 - k.cy) / k.fy
    if min(left, right, top, bottom) <= 0:
        raise InputError(
            f"the principal point ({k.cx:.1f}, {k.cy:.1f}) px lies outside the {k.width}x"
            f"{k.height} frame: no crop puts it at the centre; export nerfstudio or colmap"
        )
    # The smallest focal length whose window stays inside the frame on every side.
    f = max(
        (pcx + 0.5) / left, (w - 0.5 - pcx) / right, (pcy + 0.5) / top, (h - 0.5 - pcy) / bottom
    )
    kept = (w / f) * (h / f) / ((left + right) * (top + bottom))
    if kept < MIN_KEPT:
        raise InputError(
            f"putting this camera's principal point ({k.cx:.1f}, {k.cy:.1f}) px of a {k.width}x"
            f"{k.height} frame at the centre of a {w}x{h} image keeps {kept:.0%} of the frame "
            f"(under {MIN_KEPT:.0%}); export nerfstudio or colmap, which carry the camera as it is"
        )
    sx, sy = f / k.fx, f / k.fy
    camera = Camera(width=w, height=h, fx=f, fy=f, cx=pcx, cy=pcy)
    return Reframe(sx, sy, pcx - sx * k.cx, pcy - sy * k.cy, camera, float(kept))


def _warp(img: np.ndarray, r: Reframe, interp: int) -> np.ndarray:
    """Apply the affine map; a shrink first goes through INTER_AREA so it does not alias."""
    sx, sy, tx, ty = r.sx, r.sy, r.tx, r.ty
    w, h = r.camera.width, r.camera.height
    if min(sx, sy) < 0.8:
        h0, w0 = img.shape[:2]
        w1, h1 = max(1, round(w0 * min(sx, 1.0))), max(1, round(h0 * min(sy, 1.0)))
        img = cv2.resize(img, (w1, h1), interpolation=cv2.INTER_AREA)
        # u1 = (u + 0.5) * w1 / w0 - 0.5 (pixel centres); compose with the remaining map.
        ax, ay = w1 / w0, h1 / h0
        tx, ty = tx + sx * (0.5 / ax - 0.5), ty + sy * (0.5 / ay - 0.5)
        sx, sy = sx / ax, sy / ay
    m = np.array([[sx, 0.0, tx], [0.0, sy, ty]])
    return cv2.warpAffine(img, m, (w, h), flags=interp, borderMode=cv2.BORDER_REPLICATE)
