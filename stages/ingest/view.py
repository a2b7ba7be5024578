"""`01_ingest/frames.json` (docs/formats.md) and the only reader of 01_ingest.

Every other stage, command and report asks `IngestView` for a frame's image, mask, file or
ground truth, so the folder layout is written here once, beside `FramesFile`, which the ingest
stage writes.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np
from pydantic import BaseModel, Field

from endopipe.pipeline.errors import InputError
from endopipe.pipeline.stage import read_summary
from endopipe.stages.camera import Camera
from endopipe.stages.ingest.rig_check import RigCheck
from endopipe.stages.ingest.summary import IngestSummary
from endopipe.stages.io.datasets import open_ground_truth
from endopipe.stages.io.ground_truth import GroundTruthSource
from endopipe.stages.io.images import list_images

FRAMES_FILE = "frames.json"
FOV_FILE = "fov_mask.png"
CONTACT_SHEET_FILE = "contact_sheet.png"


class FrameEntry(BaseModel):
    """One kept frame: endopipe's number, its position in the input, and its files."""

    index: int = Field(description="endopipe's frame number")
    source_index: int = Field(description="position in the input = the ground truth's number")
    time_s: float | None = Field(None, description="time in the video (None for images)")
    file: str = Field(description="the frame, relative to 01_ingest")
    mask: str = Field(description="its mask (255 = use), relative to 01_ingest")
    tool: str | None = Field(
        None, description="its tool mask (255 = tool), relative to 01_ingest; None: no tool masks"
    )
    tool_share: float | None = Field(None, description="the share of the frame on a tool")
    stereo: str | None = Field(
        None,
        description="its stereo depth (float32 mm, 0 = unknown), relative to 01_ingest; None: "
        "no right view matched",
    )
    stereo_share: float | None = Field(
        None, description="the share of the field of view the stereo depth covers"
    )
    depth_prior: str | None = Field(
        None,
        description="its depth prior (`--depth-prior`: float32, relative, 0 = unknown) at the "
        "working size, relative to 01_ingest; None: no map for this frame",
    )


class SourceInfo(BaseModel):
    path: str
    kind: str


class KnownPoses(BaseModel):
    """Poses the input came with that are not ground truth (EndoNeRF's poses_bounds.npy): kept
    for the stages that may start from them, never scored against."""

    source: str = Field(description="where they came from")
    c2w: dict[int, list[list[float]]] = Field(description="OpenCV c2w 4x4 by frame index")


class StereoInfo(BaseModel):
    """Where the stereo depth in stereo/ came from: a rig matched here, or a data set's maps."""

    source: str = Field(description="where the right views and baseline, or the maps, were read")
    baseline_mm: float | None = Field(
        description="distance between the eyes, mm; None: the data set's own depth maps"
    )
    matcher: str = Field(description="how the depth was matched, or that it was given")
    rig: RigCheck | None = Field(
        None, description="the rig checked against its images: pairing and rows (rig_check.py)"
    )


class FramesFile(BaseModel):
    """frames.json: written by the ingest stage, read only through `IngestView`."""

    frames: list[FrameEntry]
    intrinsics: Camera | None = None
    width: int
    height: int
    source: SourceInfo | None = None
    gt_dir: str | None = None
    fov_shape: str | None = None
    dropped: dict[str, int] = Field(default_factory=dict)
    dropped_frames: dict[str, list[int]] = Field(
        default_factory=dict,
        description="A recording's timeline: the source_index of each frame not kept, by reason "
        "(frames kept by content only).",
    )
    tools: str | None = Field(
        None,
        description="Where the tool masks came from and how they were read ('masks/ (255 = "
        "tool)', 'detected'); None: no tool masks.",
    )
    known_poses: KnownPoses | None = None
    stereo: StereoInfo | None = Field(
        None, description="The stereo rig whose depth is in stereo/; None: no stereo depth."
    )
    depth_prior: str | None = Field(
        None,
        description="The folder the depth prior in depth_prior/ was read from (`--depth-prior`); "
        "None: none given.",
    )
    one_pair: bool = Field(
        False,
        description="A stereo pair alone (too few frames to pose): its depth is the rig's, with "
        "no camera path and no field.",
    )


class IngestView:
    """Typed access to 01_ingest for downstream stages: frames by endopipe index."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.file = FramesFile.model_validate_json((self.folder / FRAMES_FILE).read_text())
        self.frames: list[FrameEntry] = self.file.frames
        self.intrinsics: Camera | None = self.file.intrinsics
        self.width: int = self.file.width
        self.height: int = self.file.height
        self.gt_dir = Path(self.file.gt_dir) if self.file.gt_dir else None

    # --- frames -------------------------------------------------------------------------------
    @cached_property
    def _by_index(self) -> dict[int, FrameEntry]:
        return {f.index: f for f in self.frames}

    @cached_property
    def summary(self) -> IngestSummary:
        """The stage's summary in its manifest, as the model the stage wrote (SummaryMismatch
        when the folder was written with other fields)."""
        return read_summary(self.folder, IngestSummary)

    def frame(self, index: int) -> FrameEntry:
        """The entry of endopipe frame `index` (KeyError when ingest did not keep it)."""
        return self._by_index[index]

    @property
    def one_pair(self) -> bool:
        """Whether the input is a stereo pair alone: depth from the rig, no path, no field."""
        return self.file.one_pair

    @property
    def has_stereo(self) -> bool:
        """Whether ingest matched a stereo rig's depth (01_ingest/stereo/; its maps are read by
        `stereo_depth(i)`)."""
        return self.file.stereo is not None

    @property
    def stereo_measured_by(self) -> str:
        """Who measured the metric depth in stereo/, for the log's words: a rig's two eyes
        matched here, or the data set's own depth maps (None baseline: given, not matched)."""
        info = self.file.stereo
        if info is not None and info.baseline_mm is None:
            return "the data set's depth maps"
        return "the stereo rig"

    def has_frame(self, index: int) -> bool:
        return index in self._by_index

    @property
    def indices(self) -> list[int]:
        return [f.index for f in self.frames]

    @property
    def frames_dir(self) -> Path:
        """The folder of the frames (COLMAP reads them from it by file name)."""
        return self.image_path(self.frames[0].index).parent

    def index_by_name(self) -> dict[str, int]:
        """Frame file name ("000012.png", COLMAP's image name) -> frame index, in frame order."""
        return {Path(f.file).name: f.index for f in self.frames}

    def image_path(self, i: int) -> Path:
        return self.folder / self.frame(i).file

    def mask_path(self, i: int) -> Path:
        return self.folder / self.frame(i).mask

    def image(self, i: int) -> np.ndarray:
        """RGB uint8 of frame i (endopipe index)."""
        return cv2.cvtColor(cv2.imread(str(self.image_path(i))), cv2.COLOR_BGR2RGB)

    def mask(self, i: int) -> np.ndarray:
        """uint8 mask, 255 = usable (inside the field of view, not specular)."""
        return cv2.imread(str(self.mask_path(i)), cv2.IMREAD_GRAYSCALE)

    def tool_mask(self, i: int) -> np.ndarray | None:
        """bool (H, W), True on a tool (given with the input or detected), or None when ingest
        has no tool mask for frame i: the depth under a tool is inferred, not observed."""
        file = self.frame(i).tool
        if file is None or not (self.folder / file).is_file():
            return None
        return cv2.imread(str(self.folder / file), cv2.IMREAD_GRAYSCALE) > 127

    def stereo_depth(self, i: int) -> np.ndarray | None:
        """float32 z-depth in mm (0 = unknown) of frame i from the input's stereo rig, on the
        working frame's pixel grid; None when ingest matched no right view for it. Metric:
        a scale the monocular stages cannot have."""
        file = self.frame(i).stereo
        if file is None or not (self.folder / file).is_file():
            return None
        return np.load(self.folder / file).astype(np.float32, copy=False)

    @property
    def has_depth_prior(self) -> bool:
        """Whether the user gave depth maps (`--depth-prior`), read by `depth_prior(i)`."""
        return self.file.depth_prior is not None

    def depth_prior(self, i: int) -> np.ndarray | None:
        """float32 depth of frame i from the user's depth prior, on the working frame's pixel
        grid, 0 = unknown; None when there is no map for it. Relative: its scale and shift are
        unknown, so it is used only up to them."""
        file = self.frame(i).depth_prior
        if file is None or not (self.folder / file).is_file():
            return None
        return np.load(self.folder / file).astype(np.float32, copy=False)

    def known_poses(self) -> dict[int, np.ndarray] | None:
        """The input's own poses (not ground truth) by frame index, or None."""
        known = self.file.known_poses
        return None if known is None else {i: np.asarray(m) for i, m in known.c2w.items()}

    @property
    def fov_path(self) -> Path:
        return self.folder / FOV_FILE

    @property
    def contact_sheet_path(self) -> Path:
        """contact_sheet.png: the kept frames with their masks (for the report; may be absent)."""
        return self.folder / CONTACT_SHEET_FILE

    def fov(self) -> np.ndarray | None:
        """uint8 field-of-view mask of the sequence (255 = inside the scope's image), or None
        when the folder has none (hand-made test folders)."""
        path = self.fov_path
        return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) if path.is_file() else None

    # --- names: which frame a file of poses or ground truth means -----------------------------
    def source_file_names(self) -> list[str]:
        """The input's image file names in source order (empty for a video or a missing
        input): an image folder's own names, for files named after them."""
        src = Path(self.file.source.path) if self.file.source else None
        return [p.name for p in list_images(src)] if src is not None and src.is_dir() else []

    def index_by_stem(self) -> dict[str, int]:
        """endopipe's file stem ("000012") -> frame index."""
        return {Path(f.file).stem: f.index for f in self.frames}

    def index_by_source_stem(self) -> dict[str, int]:
        """The input file's stem (image folders) -> frame index."""
        names = self.source_file_names()
        return {
            Path(names[f.source_index]).stem: f.index
            for f in self.frames
            if f.source_index < len(names)
        }

    def index_by_source_index(self) -> dict[int, int]:
        """Position in the input -> frame index."""
        return {f.source_index: f.index for f in self.frames}

    # --- ground truth ---------------------------------------------------------------------------
    def ground_truth(self) -> GroundTruthSource | None:
        """The input's ground truth (any format `open_ground_truth` reads), or None."""
        return open_ground_truth(self.gt_dir) if self.gt_dir is not None else None

    def truth_supervised(self, gt: GroundTruthSource | None) -> str | None:
        """The ground truth's depth folder when the depth that supervised the field (a depth
        prior, a data set's own depth) is the ground truth's own maps (EndoNeRF's depth/ both)
        or holds its values (a synthetic case's exact depth/): scores against it are then no
        independent check. None otherwise."""
        if gt is None or not self.frames:
            return None
        depth_file = getattr(gt, "depth_file", None)
        first = depth_file(self.frames[0].source_index) if depth_file is not None else None
        prior = self.file.depth_prior
        if first is not None and prior and Path(prior).resolve() == Path(first).resolve().parent:
            return str(Path(first).resolve().parent)
        if not self._equals_truth(gt):
            return None
        if first is not None:
            return str(Path(first).resolve().parent)
        return str(getattr(gt, "dir", None) or "the ground truth")

    def _equals_truth(self, gt: GroundTruthSource, frames: int = 5) -> bool:
        """Whether the depth that supervised (stereo/ of a data set's own depth, or the depth
        prior up to scale) is the ground truth's values (within 0.2%) on a few frames: a
        synthetic case whose depth/ is its exact truth."""
        given = self.file.stereo is not None and self.file.stereo.baseline_mm is None
        if not given and not self.has_depth_prior:
            return False
        checked = 0
        for f in self.frames[:: max(1, len(self.frames) // frames)][:frames]:
            ours = self.stereo_depth(f.index) if given else self.depth_prior(f.index)
            truth = gt.depth(f.source_index) if ours is not None else None
            if ours is None or truth is None:
                continue
            if truth.shape != ours.shape:
                truth = cv2.resize(truth, ours.shape[::-1], interpolation=cv2.INTER_NEAREST)
            both = (ours > 0) & (truth > 0)
            if both.sum() < 100:
                continue
            ratio = ours[both] / truth[both]
            if not given:  # a prior is relative: up to its scale
                ratio = ratio / np.median(ratio)
            if np.median(np.abs(ratio - 1.0)) > 0.002:
                return False
            checked += 1
        return checked > 0

    def ground_truth_for_scores(self, log: Callable[[str], None]) -> GroundTruthSource | None:
        """The ground truth where it only scores a stage's output: one that can no longer be
        read (the case moved, the data set unmounted) is logged and ignored, not fatal."""
        try:
            return self.ground_truth()
        except InputError as e:
            log(f"ground truth ignored: {e}")
            return None
