"""The user's depth prior (`--depth-prior`) for the kept frames, at the working size, in
01_ingest/depth_prior/: read once here so later stages see it on the frames' own pixel grid.

Resampled without inventing depth: a map larger than the working frame is averaged over its
known pixels only (a working pixel with less than half its footprint known stays unknown), a
smaller one is repeated (nearest). Unknown (0, NaN, inf in the file) stays 0, and so does
everything outside the scope's field of view."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from endopipe.stages.io.depth_prior import DepthPrior

PRIOR_DIR = "depth_prior"
#: A working pixel needs at least this share of its footprint known to get the average.
MIN_KNOWN = 0.5


class FramePrior:
    """The depth prior of each kept frame, or nothing (`active` False: none was given)."""

    def __init__(self, prior: DepthPrior | None, source_size: tuple[int, int]) -> None:
        self.prior, self.source_size = prior, source_size

    @property
    def active(self) -> bool:
        return self.prior is not None

    def of(self, source_index: int, size: tuple[int, int], fov: np.ndarray) -> np.ndarray | None:
        """float32 (height, width) at the working `size` (width, height), 0 = unknown; None
        when the frame has no map."""
        assert self.prior is not None
        depth = self.prior.read(source_index, self.source_size)
        if depth is None:
            return None
        depth = resample(depth, size)
        depth[fov == 0] = 0.0
        return depth

    @staticmethod
    def write(out: Path, name: str, depth: np.ndarray) -> str:
        """depth_prior/<name>.npy under `out`; the path relative to it."""
        (out / PRIOR_DIR).mkdir(exist_ok=True)
        rel = f"{PRIOR_DIR}/{name}.npy"
        np.save(out / rel, depth.astype(np.float32))
        return rel

    def line(self, got: int, kept: int) -> str:
        """The log's line: how many kept frames had a map, and from where."""
        assert self.prior is not None
        return (
            f"depth prior for {got} of {kept} frames ({self.prior.folder}): relative, in "
            f"01_ingest/{PRIOR_DIR}/"
        )


def resample(depth: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """`depth` (0 = unknown) at `size` (width, height): averaged over the known pixels of each
    footprint when shrinking, repeated (nearest) otherwise."""
    h, w = depth.shape
    if (w, h) == size:
        return depth.astype(np.float32, copy=True)
    if w >= size[0] and h >= size[1]:
        known = (depth > 0).astype(np.float32)
        total = cv2.resize(depth * known, size, interpolation=cv2.INTER_AREA)
        share = cv2.resize(known, size, interpolation=cv2.INTER_AREA)
        ok = share >= MIN_KNOWN
        return np.where(ok, total / np.maximum(share, 1e-6), 0.0).astype(np.float32)
    return cv2.resize(depth, size, interpolation=cv2.INTER_NEAREST).astype(np.float32)
