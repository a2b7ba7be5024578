"""Hamlyn, rectified release: read in place, nothing copied.

```
rectifiedNN/
  image01/0000000000.jpg ...   left images (endopipe's frames)
  image02/0000000000.jpg ...   right images (unused)
  depth01/0000000000.png ...   uint16 depth in mm from stereo: PSEUDO ground truth
  intrinsics.txt               3x3 (or 3x4 projection) matrix of the rectified left camera
```

No poses. The depth comes from stereo matching, not a measurement, so it is labelled
`gt_kind: "pseudo"` everywhere it is used.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.sources import ImageListSource, list_images

NAME = "hamlyn"
LAYOUT = "rectifiedNN/ with image01/*.jpg, depth01/*.png (mm), intrinsics.txt"
GT_KIND = "pseudo"


def is_sequence(path: Path) -> bool:
    left = path / "image01"
    return path.is_dir() and left.is_dir() and bool(list_images(left))


def frame_number(path: Path) -> int | None:
    """The number in a file name (`0000000012.jpg` -> 12); None when it has none."""
    digits = "".join(c if c.isdigit() else " " for c in path.stem).split()
    return int(digits[-1]) if digits else None


def read_intrinsics(seq: Path, first_frame: Path) -> Camera | None:
    """intrinsics.txt: the 3x3 camera matrix, or a 3x4 projection whose 3x3 part is read."""
    path = seq / "intrinsics.txt"
    if not path.is_file():
        return None
    try:
        values = np.array(path.read_text().replace(",", " ").split(), dtype=np.float64)
    except ValueError:
        raise InputError(f"{path} must hold a 3x3 or 3x4 matrix of numbers") from None
    if values.size not in (9, 12):
        raise InputError(f"{path} holds {values.size} numbers; expected a 3x3 or 3x4 matrix")
    K = values.reshape(3, -1)[:, :3]
    image = cv2.imread(str(first_frame), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"cannot read image {first_frame}; remove it or replace it")
    h, w = image.shape[:2]
    return Camera(width=w, height=h, fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2])


class HamlynSource(ImageListSource):
    kind = "hamlyn"

    def ground_truth(self) -> HamlynGroundTruth | None:
        return HamlynGroundTruth(self.path) if self.gt_dir is not None else None


def open_sequence(path: Path, intrinsics: Camera | None = None) -> HamlynSource:
    path = Path(path)
    files = list_images(path / "image01") if (path / "image01").is_dir() else []
    if not files:
        raise InputError(f"{path} is not a Hamlyn rectified sequence ({LAYOUT})")
    intrinsics = intrinsics or read_intrinsics(path, files[0])
    gt_dir = path if (path / "depth01").is_dir() else None
    return HamlynSource(path, files, intrinsics, gt_dir)


def ground_truth(path: Path) -> HamlynGroundTruth:
    return HamlynGroundTruth(path)


class HamlynGroundTruth:
    """depth01/ (uint16 mm, stereo-derived: pseudo ground truth) matched to image01/ by number."""

    dataset = NAME
    kind = GT_KIND
    units = "mm"

    def __init__(self, seq: Path) -> None:
        self.dir = Path(seq)
        self.frames = list_images(self.dir / "image01")
        depth_dir = self.dir / "depth01"
        files = list_images(depth_dir) if depth_dir.is_dir() else []
        self._count = len(files)
        by_number = {frame_number(f): f for f in files}
        if None not in by_number and len(by_number) == len(files):  # zero padding may differ
            self._files = [by_number.get(frame_number(f)) for f in self.frames]
        else:  # names without numbers: the i-th depth file is frame i's
            self._files = [files[i] if i < len(files) else None for i in range(len(self.frames))]

    def depth_file(self, source_index: int) -> Path | None:
        if not 0 <= source_index < len(self._files):
            return None
        return self._files[source_index]

    def depth(self, source_index: int) -> np.ndarray | None:
        path = self.depth_file(source_index)
        if path is None:
            return None
        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise InputError(f"cannot read Hamlyn depth {path}")
        if raw.ndim == 3:
            raw = raw[..., 0]
        return raw.astype(np.float32)  # already millimetres; 0 = no stereo match

    def has_depth(self, source_index: int) -> bool:
        return self.depth_file(source_index) is not None

    def depth_count(self) -> int:
        return self._count

    def has_poses(self) -> bool:
        return False

    def poses(self) -> list[np.ndarray]:
        return []
