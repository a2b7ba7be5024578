"""C3VD (Colonoscopy 3D Video Dataset): one sequence per folder, read in place.

```
cecum_t1_a/
  0000_color.png ...     frames (endopipe's source_index = position in numeric order)
  0000_depth.tiff ...    uint16 z-depth: depth_mm = v * 100 / 65535 (0 = invalid)
  pose.txt               one line per frame: 16 comma-separated values, column-major,
                         camera-to-world, millimetres
  intrinsics.json        optional, endopipe format (C3VD ships a fisheye calibration instead)
```

File-name zero padding differs between copies (`0_color.png`, `0000_color.png`): files are
globbed and sorted by their number, and pose line n belongs to frame number n.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.frame_truth import NumberedGroundTruth, numbered
from endopipe.stages.io.images import ImageListSource
from endopipe.stages.io.intrinsics import load_intrinsics_file

NAME = "c3vd"
LAYOUT = "a folder of NNNN_color.png with NNNN_depth.tiff and pose.txt"
GT_KIND = "exact"
COLOR = re.compile(r"^(\d+)_color\.png$", re.IGNORECASE)
DEPTH = re.compile(r"^(\d+)_depth\.tiff?$", re.IGNORECASE)
DEPTH_RANGE_MM = 100.0  # uint16 full scale


def is_sequence(path: Path) -> bool:
    return path.is_dir() and any(COLOR.match(p.name) for p in path.iterdir())


def decode_depth(raw: np.ndarray) -> np.ndarray:
    """uint16 tiff values -> float32 mm (0 stays 0 = invalid)."""
    return (raw.astype(np.float64) * (DEPTH_RANGE_MM / 65535.0)).astype(np.float32)


def encode_depth(depth_mm: np.ndarray) -> np.ndarray:
    """float mm -> the dataset's uint16 encoding (quantisation step 100/65535 mm)."""
    v = np.round(np.asarray(depth_mm, np.float64) * (65535.0 / DEPTH_RANGE_MM))
    return np.clip(v, 0, 65535).astype(np.uint16)


def parse_pose_line(line: str) -> np.ndarray:
    """16 comma-separated values, column-major -> 4x4 camera-to-world (mm)."""
    values = [float(v) for v in line.replace(",", " ").split()]
    if len(values) != 16:
        raise ValueError(f"expected 16 values, got {len(values)}")
    return np.array(values, dtype=np.float64).reshape(4, 4).T


def format_pose_line(c2w: np.ndarray) -> str:
    """The inverse of parse_pose_line: a 4x4 written column-major, comma-separated."""
    return ",".join(repr(float(v)) for v in np.asarray(c2w, np.float64).T.reshape(-1))


def read_poses(path: Path) -> list[np.ndarray]:
    poses = []
    for n, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            poses.append(parse_pose_line(line))
        except ValueError as e:
            raise InputError(f"{path} line {n}: {e}; C3VD poses are 16 values a line") from None
    return poses


def find_intrinsics(seq: Path) -> Camera | None:
    for folder in (seq, seq.parent):
        if (folder / "intrinsics.json").is_file():
            return load_intrinsics_file(folder / "intrinsics.json")
    return None


class C3VDGroundTruth(NumberedGroundTruth):
    """Depth tiffs and pose.txt of one C3VD sequence, indexed by source_index."""

    dataset = NAME
    kind = GT_KIND
    title = "C3VD"
    frame_pattern = COLOR
    depth_pattern = DEPTH
    decode_depth = staticmethod(decode_depth)

    def has_poses(self) -> bool:
        return (self.dir / "pose.txt").is_file()

    def poses(self) -> list[np.ndarray]:
        if not self.has_poses():
            return []
        lines = read_poses(self.dir / "pose.txt")
        if self.numbers and max(self.numbers) < len(lines):
            return [lines[n] for n in self.numbers]  # line n is frame number n
        if len(lines) == len(self.numbers):
            return lines
        raise InputError(
            f"{self.dir / 'pose.txt'} has {len(lines)} poses for {len(self.numbers)} frames "
            f"numbered up to {max(self.numbers)}"
        )


class C3VDSource(ImageListSource):
    kind = NAME
    truth = C3VDGroundTruth


def open_sequence(path: Path, intrinsics: Camera | None = None) -> C3VDSource:
    path = Path(path)
    frames = numbered(path, COLOR)
    if not frames:
        raise InputError(f"{path} is not a C3VD sequence ({LAYOUT})")
    intrinsics = intrinsics or find_intrinsics(path)
    has_gt = (path / "pose.txt").is_file() or bool(numbered(path, DEPTH))
    return C3VDSource(path, [f for _, f in frames], intrinsics, path if has_gt else None)


def ground_truth(path: Path) -> C3VDGroundTruth:
    return C3VDGroundTruth(path)
