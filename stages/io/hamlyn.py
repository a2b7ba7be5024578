"""Hamlyn, rectified: read in place, nothing copied, in either layout users download.

```
rectifiedNN/                   the rectified release
  image01/0000000000.jpg ...   left images (endopipe's frames)
  image02/0000000000.jpg ...   right images (unused)
  depth01/0000000000.png ...   uint16 depth in mm from stereo: PSEUDO ground truth
  intrinsics.txt               3x3 (or 3x4 projection) matrix of the rectified left camera

rectifiedNN/                   the release with Endo-Depth-and-Motion
  color/0000000000.jpg ...     left images
  depth/0000000000.png ...     uint16 depth in mm from stereo
  intrinsics.txt
```

No poses. The depth comes from stereo matching, not a measurement, so it is labelled
`gt_kind: "pseudo"` everywhere it is used.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.frame_truth import PerFrameGroundTruth
from endopipe.stages.io.images import ImageListSource, list_images
from endopipe.stages.io.intrinsics import read_camera_matrix

NAME = "hamlyn"
LAYOUT = (
    "rectifiedNN/ with image01/*.jpg, depth01/*.png (mm), intrinsics.txt; or color/*.jpg, "
    "depth/*.png (mm), intrinsics.txt"
)
GT_KIND = "pseudo"
#: (left images, depth) folders of each layout, in detection order. A folder of images named
#: color/ is common, so that layout also needs its intrinsics.txt to be taken for Hamlyn.
FOLDERS = (("image01", "depth01"), ("color", "depth"))


def folders(path: Path) -> tuple[str, str] | None:
    """The (images, depth) folder names of the layout `path` has, or None."""
    for images, depth in FOLDERS:
        needs_intrinsics = images == "color"
        if needs_intrinsics and not (path / "intrinsics.txt").is_file():
            continue
        if (path / images).is_dir() and list_images(path / images):
            return images, depth
    return None


def is_sequence(path: Path) -> bool:
    return Path(path).is_dir() and folders(Path(path)) is not None


def frame_number(path: Path) -> int | None:
    """The number in a file name (`0000000012.jpg` -> 12); None when it has none."""
    digits = "".join(c if c.isdigit() else " " for c in path.stem).split()
    return int(digits[-1]) if digits else None


def read_intrinsics(seq: Path, first_frame: Path) -> Camera | None:
    """intrinsics.txt: the 3x3 camera matrix, or a 3x4 projection whose 3x3 part is read."""
    return read_camera_matrix(seq / "intrinsics.txt", first_frame, projection=True)


class HamlynGroundTruth(PerFrameGroundTruth):
    """depth01/ or depth/ (uint16 mm, stereo-derived: pseudo ground truth) matched to the left
    images by number."""

    dataset = NAME
    kind = GT_KIND
    title = "Hamlyn"

    def __init__(self, seq: Path) -> None:
        images, depth = folders(Path(seq)) or FOLDERS[0]
        self.frames = list_images(Path(seq) / images)
        depth_dir = Path(seq) / depth
        files = list_images(depth_dir) if depth_dir.is_dir() else []
        super().__init__(seq, depth_of_frames(self.frames, files), len(files))

    def decode_depth(self, raw: np.ndarray) -> np.ndarray:
        return raw.astype(np.float32)  # already millimetres; 0 = no stereo match


def depth_of_frames(frames: list[Path], files: list[Path]) -> list[Path | None]:
    """Each frame's depth file: the one with its number when every depth file has its own (zero
    padding may differ), else the i-th file for frame i."""
    by_number = {frame_number(f): f for f in files}
    if None not in by_number and len(by_number) == len(files):
        return [by_number.get(frame_number(f)) for f in frames]
    return [files[i] if i < len(files) else None for i in range(len(frames))]


class HamlynSource(ImageListSource):
    kind = NAME
    truth = HamlynGroundTruth


def open_sequence(path: Path, intrinsics: Camera | None = None) -> HamlynSource:
    path = Path(path)
    layout = folders(path)
    if layout is None:
        raise InputError(f"{path} is not a Hamlyn rectified sequence ({LAYOUT})")
    images, depth = layout
    files = list_images(path / images)
    intrinsics = intrinsics or read_intrinsics(path, files[0])
    gt_dir = path if (path / depth).is_dir() else None
    return HamlynSource(path, files, intrinsics, gt_dir)


def ground_truth(path: Path) -> HamlynGroundTruth:
    return HamlynGroundTruth(path)
