"""What every reader hands the pipeline: frames, with the intrinsics and truth they came with."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from endopipe.pipeline.cache import digest_path, digest_text
from endopipe.stages.camera import Camera
from endopipe.stages.io.depth_prior import DepthPrior
from endopipe.stages.io.given_depth import GivenDepth
from endopipe.stages.io.ground_truth import GroundTruthSource, open_case_truth
from endopipe.stages.io.stereo_pairs import StereoPairs
from endopipe.stages.io.tool_masks import ToolMasks


@dataclass
class Frame:
    source_index: int
    time_s: float | None
    rgb: np.ndarray  # HxWx3 uint8


class InputSource:
    """Frames plus whatever the input says about intrinsics and ground truth."""

    kind: str = "video"

    def __init__(self, path: Path, intrinsics: Camera | None, gt_dir: Path | None) -> None:
        self.path = path
        self.intrinsics = intrinsics
        self.gt_dir = gt_dir
        #: Tool masks given with the input (a case folder's or a data set's masks/), or None.
        self.tool_masks: ToolMasks | None = None
        #: Poses the input comes with that are not ground truth (EndoNeRF's poses_bounds.npy):
        #: OpenCV c2w by source_index, and where they came from; None when it has none.
        self.known_poses: list[np.ndarray] | None = None
        self.known_poses_from: str | None = None
        #: Rectified right views of the frames (a stereo data set, `--right`), or None.
        self.stereo: StereoPairs | None = None
        #: Depth maps made elsewhere (`--depth-prior`), relative: by source_index, or None.
        self.depth_prior: DepthPrior | None = None
        #: Metric depth the data set ships (EndoNeRF's depth/ in mm), by source_index, or None.
        self.given_depth: GivenDepth | None = None
        #: What the reader found checking its calibration against the frames (a calibration
        #: stated for another image size, rescaled), in one line; None: it fit as given.
        self.calibration_said: str | None = None
        #: One line each of what the reader did to the input that the run should say (frames
        #: cropped to one size, a lens fitted to the data set's calibration).
        self.notes: list[str] = []

    def frames(self) -> Iterator[Frame]:  # pragma: no cover - abstract
        raise NotImplementedError

    def frame_count(self) -> int | None:
        return None

    def digest(self) -> str:
        return digest_text("|".join([digest_path(self.path), *self.given_digests()]))

    def given_digests(self) -> list[str]:
        """What came with the frames and makes the ingest key too (any reader's digest adds
        them): the intrinsics, tool masks, right views, depth prior and depth, those given."""
        parts = [self.intrinsics.model_dump_json()] if self.intrinsics is not None else []
        for given in (self.tool_masks, self.stereo, self.depth_prior, self.given_depth):
            if given is not None:
                parts.append(given.digest())
        return parts

    def ground_truth(self) -> GroundTruthSource | None:
        """The input's ground truth for evaluation (None when it has none): an endopipe case
        folder's gt/ here; a data set reader's source reads the set's own files instead."""
        return open_case_truth(self.gt_dir) if self.gt_dir is not None else None
