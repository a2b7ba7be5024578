"""Whether and how the kept frames get stereo depth: the input's right views matched to each
left frame at the working size (stereo.py), written to 01_ingest/stereo/.

One place decides (the config's mode, the input's right views, a pinhole camera to measure
with), so the stage, its log, frames.json and the summary say the same thing.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.ingest.config import StereoConfig
from endopipe.stages.ingest.selection import resize
from endopipe.stages.ingest.stereo import match_depth
from endopipe.stages.io.stereo_pairs import StereoPairs

STEREO_DIR = "stereo"
MATCHER = "OpenCV StereoSGBM (3-way), left-right checked"


class FrameStereo:
    """Stereo depth for the kept frames, or nothing (`active` False) and why (`skipped`)."""

    def __init__(self, pairs: StereoPairs | None, camera: Camera | None, cfg: StereoConfig) -> None:
        self.pairs, self.camera, self.cfg = pairs, camera, cfg
        self.skipped = self._why_not()
        if self.skipped is not None and cfg.mode == "on":
            raise InputError(
                f"ingest.stereo.mode=on but {self.skipped}; --set ingest.stereo.mode=auto"
            )

    def _why_not(self) -> str | None:
        if self.cfg.mode == "off":
            return "ingest.stereo.mode=off"
        if self.pairs is None:
            return "the input has no rectified right views with a baseline"
        if self.camera is None:
            return "the input's right views need the rectified camera's focal length (--intrinsics)"
        if self.camera.distorted:
            return f"a rectified pair has no lens, and this camera has one ({self.camera.model})"
        return None

    @property
    def active(self) -> bool:
        return self.skipped is None

    def of(self, source_index: int, left: np.ndarray, usable: np.ndarray) -> np.ndarray | None:
        """float32 z-depth (mm, 0 = unknown) of a kept frame (working size), matched only where
        `usable` (the field of view without highlights); None when it has no right view."""
        assert self.pairs is not None and self.camera is not None
        right = self.pairs.right(source_index)
        if right is None:
            return None
        right = resize(right, (left.shape[1], left.shape[0]))
        return match_depth(left, right, self.camera.fx, self.pairs.baseline_mm, self.cfg, usable)

    @staticmethod
    def share(depth: np.ndarray, fov: np.ndarray) -> float:
        """The share of the field of view's pixels with a depth."""
        inside = fov > 0
        return float((depth[inside] > 0).sum() / max(int(inside.sum()), 1))

    @staticmethod
    def write(out: Path, name: str, depth: np.ndarray) -> str:
        """stereo/<name>.npy under `out`; the path relative to it."""
        (out / STEREO_DIR).mkdir(exist_ok=True)
        rel = f"{STEREO_DIR}/{name}.npy"
        np.save(out / rel, depth.astype(np.float32))
        return rel

    def line(self, shares: list[float | None]) -> str:
        """The log's line: frames matched, from where, what share of the view they cover."""
        if not self.active:
            return f"stereo: none ({self.skipped})"
        got = [s for s in shares if s is not None]
        mean = f", {np.mean(got):.0%} of the field of view on average" if got else ""
        assert self.pairs is not None
        return (
            f"stereo depth for {len(got)} of {len(shares)} frames ({self.pairs.source}, baseline "
            f"{self.pairs.baseline_mm:.2f} mm){mean}: metric, in 01_ingest/{STEREO_DIR}/"
        )
