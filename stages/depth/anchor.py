"""The field's depth held to what was measured: never worse than the depth that trained it.

Why: the field learns its depth from the images and from measured depth at once, and where the
images pull one way it drifts off the measurements (on the real Hamlyn clip the field's depth
agreed with the rig's stereo to 0.051 where the stereo alone agreed with the release's to 0.032;
on the sinus recording it lay 0.111 from the authors' points where our own SfM points lay 0.078).
A measurement is better than the field's guess where it exists, and the field's shape is a
better guess between measurements than nothing.

So each frame's depth map is published as: the rig's stereo depth where the matcher measured it
(left-right checked: the stereo's own noise, no more); elsewhere the field's depth times a smooth
correction, the ratio of measured to field depth spread from the measured pixels (normalised
convolution: a Gaussian-weighted mean of the log ratios near each pixel, falling back to the
frame's median ratio where none is near). With only the SfM points (a few hundred a frame) the
correction is all there is: the field's shape, scaled locally to the points' depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from pydantic import BaseModel, Field

#: Fewest measured pixels of a frame for its correction to be fitted (else the field as it is).
MIN_MEASURED = 20
#: The weight of the frame's median ratio in the normalised convolution (as a count of pixels
#: at the kernel's peak): where fewer measurements lie near, the median takes over.
PRIOR_WEIGHT = 0.05
#: A local correction counts in full once it stands this many standard errors out of the noise
#: of the measurements near it (less is shrunk towards none).
SIGNIFICANCE = 2.0
#: A blur of twice this sigma (pixels) or more runs on the image shrunk to this sigma.
COARSE_SIGMA_PX = 16.0


class Anchored(BaseModel):
    """How one frame's published depth was made: shares of its depth pixels."""

    measured: float = Field(description="share of the frame's depth pixels measured (stereo)")
    corrected: float = Field(description="share the field filled in, corrected to the measured")
    median_ratio: float | None = Field(description="measured over field depth, median; None: none")


def anchored_depth(
    field: np.ndarray,
    measured: np.ndarray,
    paste: bool,
    sigma_px: float,
    max_ratio: float = 1.5,
) -> tuple[np.ndarray, Anchored]:
    """The field's depth map (H, W; 0 = unknown) held to `measured` (H, W; 0 = not measured, same
    units): pasted where measured when `paste` (a dense rig), and elsewhere corrected by the
    measured-to-field ratio spread over `sigma_px` pixels. Ratios beyond `max_ratio` either way
    are a measurement of something else (an occlusion edge, a mismatch) and do not count."""
    has = field > 0
    both = has & (measured > 0)
    n = int(both.sum())
    if n < MIN_MEASURED:
        return field, Anchored(measured=0.0, corrected=0.0, median_ratio=None)
    log_ratio = np.zeros(field.shape, np.float32)
    log_ratio[both] = np.log(measured[both] / field[both])
    ok = both & (np.abs(log_ratio) < np.log(max_ratio))
    if int(ok.sum()) < MIN_MEASURED:
        return field, Anchored(measured=0.0, corrected=0.0, median_ratio=None)
    median = float(np.median(log_ratio[ok]))
    correction = spread(np.where(ok, log_ratio, 0.0), ok, sigma_px, median)
    out = np.where(has, field * np.exp(correction), 0.0).astype(np.float32)
    pasted = np.zeros_like(has)
    if paste:
        pasted = measured > 0
        out = np.where(pasted, measured, out).astype(np.float32)
    total = max(int((has | pasted).sum()), 1)
    return out, Anchored(
        measured=float(pasted.sum()) / total,
        corrected=float((has & ~pasted).sum()) / total,
        median_ratio=float(np.exp(median)),
    )


def spread(values: np.ndarray, where: np.ndarray, sigma_px: float, default: float) -> np.ndarray:
    """`values` known at `where` spread over the image: normalised convolutions at sigma and
    4, 16, 64 times it, each finer one taking over where enough known pixels lie near it (a
    strip far from any measurement gets the nearest ones' value, not the frame's median);
    `default` where none lies within the coarsest. Each scale's local mean is shrunk towards
    `default` by how far it stands out of its own noise (its spread over the measurements
    near it, over their number): scattered SfM points that agree with the field on average
    move it nowhere (the bench colon's: 28% of them 5% off the truth), points that disagree
    with it together move it (the sinus's field lay 10% off its points)."""
    weight = where.astype(np.float32)
    v = values.astype(np.float32) - default
    wv, wvv = weight * v, weight * v * v
    out = np.zeros(values.shape, np.float32)
    for k in (3, 2, 1, 0):
        s = sigma_px * 4.0**k
        den, sum_v, sum_vv = wide_blur((weight, wv, wvv), s)
        mean = sum_v / np.maximum(den, 1e-12)
        var = np.maximum(sum_vv / np.maximum(den, 1e-12) - mean**2, 0)
        count = den * (2 * np.pi * s**2)  # measurements within about one sigma
        noise = SIGNIFICANCE**2 * var / np.maximum(count, 1.0)
        mean = mean * mean**2 / np.maximum(mean**2 + noise, 1e-12)
        trust = count / (count + PRIOR_WEIGHT)
        out = trust * mean + (1 - trust) * out
    return out + default


def wide_blur(images: tuple[np.ndarray, ...], sigma_px: float) -> tuple[np.ndarray, ...]:
    """Each image Gaussian-blurred at `sigma_px`. Why: a direct blur costs its kernel's width per
    pixel, and the coarsest scale of `spread` is wider than the image (64 x 16 px: three seconds
    a frame of 640 x 480 for `spread`'s blurs). A blur that wide is computed on the image shrunk
    by area averaging (which keeps local means, so the weighted means stay) to a sigma of
    COARSE_SIGMA_PX, and enlarged back: `spread` then differs from the direct blurs by
    2e-4 in log depth on a 320 x 300 frame with 300 points, 0.006 with 50
    (tests/test_depth_anchor.py), at a hundredth of the time."""
    h, w = images[0].shape
    shrink = sigma_px / COARSE_SIGMA_PX
    if shrink < 2.0:
        return tuple(cv2.GaussianBlur(im, (0, 0), sigma_px) for im in images)
    size = (max(int(round(w / shrink)), 1), max(int(round(h / shrink)), 1))
    s_small = sigma_px * size[0] / w
    out = []
    for im in images:
        small = cv2.resize(im, size, interpolation=cv2.INTER_AREA)
        small = cv2.GaussianBlur(small, (0, 0), s_small)
        out.append(cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR))
    return tuple(out)


def sparse_map(uv: np.ndarray, z: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Points' depths (N,) at pixels uv (N, 2; OpenCV centres) as a map (H, W; 0 = none), the
    nearest point kept where two fall on one pixel."""
    h, w = shape
    out = np.zeros(shape, np.float32)
    col = np.round(uv[:, 0]).astype(np.int64)
    row = np.round(uv[:, 1]).astype(np.int64)
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h) & (z > 0)
    order = np.argsort(-z[inside])  # far first: the nearest is written last
    out[row[inside][order], col[inside][order]] = z[inside][order]
    return out


@dataclass
class Anchor:
    """What a case's depth maps are held to: the rig's stereo (metric poses only: the maps are
    millimetres), else the SfM points, else nothing (`source` None)."""

    source: str | None  # "stereo" | "SfM points" | None
    measured_of: object  # frame index -> (H, W) measured depth or None
    sigma_px: float

    @classmethod
    def open(cls, mode: str, ingest, poses, dense_share: float, points_share: float) -> Anchor:
        """`mode` off; auto: the stereo when the ingest has it and the poses are metric; points:
        that, else the SfM points when the poses have tracks."""
        if mode == "off":
            return cls(None, lambda i: None, 0.0)
        if ingest.has_stereo and poses.metric:
            return cls("stereo", ingest.stereo_depth, dense_share * ingest.width)
        if mode != "points":
            return cls(None, lambda i: None, 0.0)
        obs = poses.observations(ingest.index_by_name())
        if obs is None or not len(obs.frame):
            return cls(None, lambda i: None, 0.0)
        k = poses.intrinsics
        obs.resize((k.width, k.height), (ingest.width, ingest.height))
        shape = (ingest.height, ingest.width)

        def points_of(i: int) -> np.ndarray | None:
            sel = obs.frame == i
            if not sel.any() or i not in poses.c2w:
                return None
            w2c = np.linalg.inv(poses.c2w[i])
            return sparse_map(obs.uv[sel], obs.xyz[sel] @ w2c[2, :3] + w2c[2, 3], shape)

        return cls("SfM points", points_of, points_share * ingest.width)

    def apply(self, i: int, field: np.ndarray) -> tuple[np.ndarray, Anchored | None]:
        """Frame `i`'s published depth from the field's (`anchored_depth`)."""
        measured = self.measured_of(i) if self.source else None  # type: ignore[operator]
        if measured is None:
            return field, None
        return anchored_depth(field, measured, self.source == "stereo", self.sigma_px)
