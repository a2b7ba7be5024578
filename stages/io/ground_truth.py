"""Ground truth for evaluation, one implementation per input kind behind one small protocol.

`GroundTruth` reads an endopipe case folder's `gt/` (docs/formats.md); the dataset readers in
stages/io/ (hamlyn, c3vd, simcol3d, c3vd_preview) each bring their own class that reads the
dataset's files in place (on `frame_truth.PerFrameGroundTruth`), and
`datasets.open_ground_truth` picks the one for a `gt_dir`. Every implementation answers in
endopipe's conventions: depth is float32 z-depth in mm (0 = invalid) at the input frame's
resolution, poses are OpenCV camera-to-world 4x4 in mm, and both are indexed by `source_index`
(frame i of the input, as in 01_ingest/frames.json).
`kind` says how far to trust it: "exact" (rendered or measured), "pseudo" (e.g. Hamlyn's
stereo-derived depth) or "relative" (an affine proxy of depth in arbitrary units, e.g. C3VD's
preview panel: compared only up to scale and shift, or by rank); evaluation outputs must carry
it as `gt_kind`.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Protocol, runtime_checkable

import cv2
import numpy as np

from endopipe.pipeline.errors import InputError

GtKind = Literal["exact", "pseudo", "relative"]


@runtime_checkable
class GroundTruthSource(Protocol):
    """What evaluation needs from any ground truth."""

    dataset: str  # "endopipe" | "hamlyn" | "c3vd" | "simcol3d" | "c3vd_preview"
    kind: GtKind
    units: str  # "mm"

    def depth(self, source_index: int) -> np.ndarray | None:
        """float32 z-depth (mm, 0 = invalid) of input frame `source_index`, or None."""
        ...

    def has_depth(self, source_index: int) -> bool:
        """Whether input frame `source_index` has a depth map (without reading it)."""
        ...

    def depth_count(self) -> int:
        """How many depth maps the truth holds (to compare with the input's frame count)."""
        ...

    def has_poses(self) -> bool: ...

    def poses(self) -> list[np.ndarray]:
        """OpenCV camera-to-world 4x4 poses (mm), one per input frame, by source_index."""
        ...


def holds_case_truth(gt_dir: Path) -> bool:
    """Whether `gt_dir` is an endopipe case folder's gt/ (poses.json and/or depth/)."""
    return (gt_dir / "poses.json").is_file() or (gt_dir / "depth").is_dir()


def open_case_truth(gt_dir: Path) -> GroundTruth:
    """An endopipe case folder's gt/; InputError when it holds nothing endopipe reads."""
    if not holds_case_truth(Path(gt_dir)):
        raise InputError(f"no ground truth that endopipe can read in {gt_dir}")
    return GroundTruth(Path(gt_dir))


class FrameRef(Protocol):
    """What the frame -> truth mapping needs of a frame (01_ingest's frames.json entries)."""

    index: int  # endopipe's frame number
    source_index: int  # the frame's position in the input = the ground truth's file number


def poses_by_frame(
    gt: GroundTruthSource | None, frames: Iterable[FrameRef]
) -> dict[int, np.ndarray] | None:
    """The frame -> truth mapping for poses, written once: GT c2w per endopipe frame index
    (None when there are no GT poses). Unreadable poses are one InputError line."""
    if gt is None or not gt.has_poses():
        return None
    try:
        poses = [np.asarray(p, dtype=np.float64) for p in gt.poses()]
        if any(p.shape != (4, 4) or not np.isfinite(p).all() for p in poses):
            raise ValueError("every pose must be a finite 4x4 matrix")
    except (ValueError, KeyError, TypeError, OSError) as e:
        where = getattr(gt, "dir", None) or gt.dataset
        raise InputError(f"cannot read the ground-truth poses in {where}: {e}") from None
    return {f.index: poses[f.source_index] for f in frames if f.source_index < len(poses)}


def depth_of_frame(gt: GroundTruthSource | None, frame: FrameRef) -> np.ndarray | None:
    """The frame -> truth mapping for depth: GT z-depth (mm, 0 = invalid) of one frame."""
    return None if gt is None else gt.depth(frame.source_index)


@dataclass(frozen=True)
class Coverage:
    """How the truth covers the kept frames: a frame without truth is silently left out of
    evaluation, so ingest shows each mismatch in one line and records it."""

    frames_without_depth: int = 0
    frames_without_pose: int = 0
    warnings: list[str] = field(default_factory=list)


def coverage(
    gt: GroundTruthSource | None, source_indices: Sequence[int], input_frames: int | None
) -> Coverage:
    """Compare the truth with the input (`input_frames` frames, None when unknown) and the kept
    frames (`source_indices`)."""
    if gt is None:
        return Coverage()
    count = gt.depth_count()
    no_depth = [i for i in source_indices if not gt.has_depth(i)] if count else []
    n_poses = _pose_count(gt)
    no_pose = [i for i in source_indices if i >= n_poses] if n_poses else []
    warnings = [
        w
        for w in (
            _mismatch(count, "depth map", no_depth, len(source_indices), input_frames),
            _mismatch(n_poses, "pose", no_pose, len(source_indices), input_frames),
        )
        if w
    ]
    return Coverage(len(no_depth), len(no_pose), warnings)


def _pose_count(gt: GroundTruthSource) -> int:
    """How many poses the truth holds; 0 when it has none or they are unreadable (the poses
    stage reports unreadable poses when it needs them)."""
    if not gt.has_poses():
        return 0
    try:
        return len(gt.poses())
    except (InputError, ValueError, KeyError, TypeError, OSError):
        return 0


def _mismatch(
    count: int, what: str, missing: list[int], kept: int, input_frames: int | None
) -> str | None:
    """One line when `count` items of truth do not match the input's frames, else None."""
    if not count:
        return None
    head = f"ground truth does not match the input: {count} {what}(s)"
    if input_frames:
        head += f" for {input_frames} frame(s)"
    if missing:
        return (
            f"{head}; {len(missing)} of the {kept} kept frame(s) have none (from input frame "
            f"{missing[0]}) and are not evaluated"
        )
    if input_frames and count > input_frames:
        return f"{head}; check that the ground truth belongs to this input"
    return None


class GroundTruth:
    """Lazy access to gt/: files are indexed by `source_index` (frame i of the input)."""

    dataset = "endopipe"
    kind: GtKind = "exact"

    def __init__(self, gt_dir: Path) -> None:
        self.dir = Path(gt_dir)

    def has_depth(self, source_index: int) -> bool:
        return (self.dir / "depth" / f"{source_index:06d}.npy").is_file()

    def depth_count(self) -> int:
        return sum(1 for _ in (self.dir / "depth").glob("*.npy"))

    def has_poses(self) -> bool:
        return (self.dir / "poses.json").is_file()

    def poses(self) -> list[np.ndarray]:
        data = json.loads((self.dir / "poses.json").read_text())
        if data.get("convention", "opencv_c2w") != "opencv_c2w":
            raise ValueError(f"gt/poses.json convention {data['convention']!r} is not opencv_c2w")
        return [np.array(p, dtype=np.float64) for p in data["poses"]]

    @property
    def units(self) -> str:
        if not self.has_poses():
            return "mm"
        return json.loads((self.dir / "poses.json").read_text()).get("units", "mm")

    def depth(self, source_index: int) -> np.ndarray | None:
        path = self.dir / "depth" / f"{source_index:06d}.npy"
        return np.load(path).astype(np.float32) if path.is_file() else None

    def specular(self, source_index: int) -> np.ndarray | None:
        path = self.dir / "specular" / f"{source_index:06d}.png"
        return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) if path.is_file() else None

    def mesh_path(self) -> Path | None:
        path = self.dir / "mesh.ply"
        return path if path.is_file() else None

    def centerline(self) -> tuple[np.ndarray, np.ndarray] | None:
        path = self.dir / "centerline.json"
        if not path.is_file():
            return None
        data = json.loads(path.read_text())
        return np.array(data["points"], dtype=np.float64), np.array(
            data["radius"], dtype=np.float64
        )
