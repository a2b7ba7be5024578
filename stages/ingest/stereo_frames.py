"""Whether and how the kept frames get stereo depth: the input's right views matched to each
left frame at the working size (stereo.py), or the metric depth a data set ships (EndoNeRF's
depth/ in mm) taken as it is, written to 01_ingest/stereo/.

One place decides (the config's mode, the input's right views or given depth, a pinhole camera
to measure with), so the stage, its log, frames.json and the summary say the same thing.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.ingest.config import StereoConfig
from endopipe.stages.ingest.rig_check import RigCheck, check_rig, mended_right
from endopipe.stages.ingest.selection import resize
from endopipe.stages.ingest.stereo import match_depth
from endopipe.stages.io.given_depth import GivenDepth
from endopipe.stages.io.stereo_pairs import StereoPairs

STEREO_DIR = "stereo"
MATCHER = "OpenCV StereoSGBM ({mode}), left-right checked"
GIVEN = "given by the data set, taken as it is (nearest pixel at the working size)"


class FrameStereo:
    """Stereo depth for the kept frames, or nothing (`active` False) and why (`skipped`)."""

    def __init__(
        self,
        pairs: StereoPairs | None,
        camera: Camera | None,
        cfg: StereoConfig,
        given: GivenDepth | None = None,
    ) -> None:
        self.pairs, self.camera, self.cfg = pairs, camera, cfg
        self.given = given if pairs is None else None  # a rig is matched; its depth is ours
        self.skipped = self._why_not()
        self.rig: RigCheck | None = None  # what check() found, when it ran
        if self.skipped is not None and cfg.mode == "on":
            raise InputError(
                f"ingest.stereo.mode=on but {self.skipped}; --set ingest.stereo.mode=auto"
            )

    def _why_not(self) -> str | None:
        if self.cfg.mode == "off":
            return "ingest.stereo.mode=off"
        if self.pairs is None and self.given is not None:
            return None
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

    def check(self, sources: list[int], images: list[np.ndarray]) -> RigCheck | None:
        """Check a rig against its images (rig_check.py) on the kept frames (`sources`, their
        source indices, and their RGB `images`: at the working size, or at the source's for a
        pair alone, whose one frame must pin the rotation): the pairing and the row offset `of`
        then matches with, in pixels of the working size. None without a rig to check."""
        if not self.active or self.pairs is None or not self.cfg.check or not sources:
            return None
        h, w = images[0].shape[:2]
        by_source = dict(zip(sources, images, strict=True))
        rig = check_rig(
            sources,
            by_source.__getitem__,
            lambda s: self._right(s, (w, h)),
            self.cfg.max_offset,
            camera=self.camera.scaled(w, h) if self.camera is not None else None,
            px=w / self.camera.width if self.camera is not None else 1.0,
        )
        if self.camera is not None and w != self.camera.width:
            rig = rig.at_width(self.camera.width, w)
        self.rig = rig
        if self.rig.refused is not None:
            if self.cfg.mode == "on":
                raise InputError(f"ingest.stereo.mode=on but {self.rig.refused}")
            self.skipped = self.rig.refused
        return self.rig

    def _right(self, source_index: int, size: tuple[int, int]) -> np.ndarray | None:
        assert self.pairs is not None
        right = self.pairs.right(source_index)
        return None if right is None else resize(right, size)

    def of(self, source_index: int, left: np.ndarray, usable: np.ndarray) -> np.ndarray | None:
        """float32 z-depth (mm, 0 = unknown) of a kept frame (working size), matched only where
        `usable` (the field of view without highlights and tools); None when it has no right
        view. A checked rig's right frame is the one its check paired, its rows shifted or the
        image turned as found."""
        if self.given is not None:
            return self._given(source_index, left, usable)
        assert self.pairs is not None and self.camera is not None
        rig = self.rig or RigCheck()
        size = (left.shape[1], left.shape[0])
        right = self.pairs.right(source_index + rig.frame_offset)
        if right is None:
            return None
        if rig.right_rotation is not None:  # turned at its own size: one resampling, not two
            own = self.camera.scaled(right.shape[1], right.shape[0])
            right = resize(mended_right(right, rig, own), size)
        else:
            right = mended_right(resize(right, size), rig, self.camera.scaled(*size))
        return match_depth(left, right, self.camera.fx, self.pairs.baseline_mm, self.cfg, usable)

    def _given(self, source_index: int, left: np.ndarray, usable: np.ndarray) -> np.ndarray | None:
        assert self.given is not None
        depth = self.given.depth(source_index)
        if depth is None:
            return None
        h, w = left.shape[:2]
        if depth.shape != (h, w):  # nearest: a mean across an edge is a depth nothing has
            depth = cv2.resize(depth, (w, h), interpolation=cv2.INTER_NEAREST)
        return np.where(usable > 0, depth, 0.0).astype(np.float32)

    @property
    def source(self) -> str:
        """Where the depth came from: the rig's right views, or the data set's maps."""
        if self.given is not None:
            return self.given.source
        assert self.pairs is not None
        return self.pairs.source

    @property
    def baseline_mm(self) -> float | None:
        return self.pairs.baseline_mm if self.pairs is not None else None

    @property
    def how(self) -> str:
        return GIVEN if self.given is not None else MATCHER.format(mode=self.cfg.matcher_mode)

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
        if self.given is not None:
            return (
                f"stereo depth for {len(got)} of {len(shares)} frames ({self.given.source}, "
                f"{GIVEN}){mean}: metric, in 01_ingest/{STEREO_DIR}/"
            )
        assert self.pairs is not None
        return (
            f"stereo depth for {len(got)} of {len(shares)} frames ({self.pairs.source}, baseline "
            f"{self.pairs.baseline_mm:.2f} mm){mean}: metric, in 01_ingest/{STEREO_DIR}/"
        )
