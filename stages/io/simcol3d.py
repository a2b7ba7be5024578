"""SimCol3D (synthetic colonoscopy from Unity): one `Frames_*` folder per sequence, read in place.

```
SyntheticColon_I/
  cam.txt                          3x3 camera matrix, row-major, pixels
  SavedPosition_S1.txt             one line per frame: x y z (Unity units = cm)
  SavedRotationQuaternion_S1.txt   one line per frame: qx qy qz qw
  Frames_S1/
    FrameBuffer_0000.png ...       frames
    Depth_0000.png ...             16-bit: depth = png / 255 / 256 * 20 cm
```

Unity is left-handed (x right, y up, z forward). Flipping the y axis of both the world and the
camera, P_opencv = F P_unity F with F = diag(1, -1, 1, 1), gives a right-handed world and an
OpenCV camera (x right, y down, z forward): the camera-to-world poses endopipe uses.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.frame_truth import NumberedGroundTruth, numbered
from endopipe.stages.io.images import ImageListSource
from endopipe.stages.io.intrinsics import read_camera_matrix

NAME = "simcol3d"
LAYOUT = "Frames_<S>/FrameBuffer_N.png + Depth_N.png, ../SavedPosition_<S>.txt, ../cam.txt"
GT_KIND = "exact"
FRAME = re.compile(r"^FrameBuffer_(\d+)\.png$", re.IGNORECASE)
DEPTH = re.compile(r"^Depth_(\d+)\.png$", re.IGNORECASE)
DEPTH_FULL_SCALE_MM = 200.0  # 20 cm
CM_TO_MM = 10.0
FLIP_Y = np.diag([1.0, -1.0, 1.0, 1.0])


def is_sequence(path: Path) -> bool:
    return path.is_dir() and any(FRAME.match(p.name) for p in path.iterdir())


def decode_depth(raw: np.ndarray) -> np.ndarray:
    """16-bit png -> float32 mm: png / 255 / 256 * 20 cm."""
    return (raw.astype(np.float64) / 255.0 / 256.0 * DEPTH_FULL_SCALE_MM).astype(np.float32)


def encode_depth(depth_mm: np.ndarray) -> np.ndarray:
    """float mm -> the dataset's 16-bit encoding (step 200 / 65280 mm)."""
    v = np.round(np.asarray(depth_mm, np.float64) / DEPTH_FULL_SCALE_MM * 255.0 * 256.0)
    return np.clip(v, 0, 65535).astype(np.uint16)


def unity_to_opencv(position: np.ndarray, quaternion_xyzw: np.ndarray) -> np.ndarray:
    """One SimCol3D pose (Unity, left-handed, cm) -> OpenCV camera-to-world 4x4 in mm."""
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_quat(np.asarray(quaternion_xyzw, np.float64)).as_matrix()
    pose[:3, 3] = np.asarray(position, np.float64) * CM_TO_MM
    return FLIP_Y @ pose @ FLIP_Y


def opencv_to_unity(c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of unity_to_opencv: (position in cm, quaternion x y z w)."""
    pose = FLIP_Y @ np.asarray(c2w, np.float64) @ FLIP_Y
    return pose[:3, 3] / CM_TO_MM, Rotation.from_matrix(pose[:3, :3]).as_quat()


def sequence_id(frames_dir: Path) -> str:
    """`Frames_S1` -> `S1` (the suffix of its pose files)."""
    return frames_dir.name.split("_", 1)[1] if "_" in frames_dir.name else frames_dir.name


def pose_files(frames_dir: Path) -> tuple[Path, Path]:
    sid = sequence_id(frames_dir)
    root = frames_dir.parent
    return root / f"SavedPosition_{sid}.txt", root / f"SavedRotationQuaternion_{sid}.txt"


def read_intrinsics(frames_dir: Path, first_frame: Path) -> Camera | None:
    """cam.txt beside the sequence folders, at the size of the frames."""
    return read_camera_matrix(frames_dir.parent / "cam.txt", first_frame)


def _read_rows(path: Path, width: int) -> np.ndarray:
    rows = []
    for n, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        values = line.replace(",", " ").split()
        if len(values) != width:
            raise InputError(f"{path} line {n}: expected {width} numbers, got {len(values)}")
        try:
            rows.append([float(v) for v in values])
        except ValueError:
            raise InputError(f"{path} line {n}: {line.strip()!r} is not {width} numbers") from None
    return np.array(rows, dtype=np.float64).reshape(-1, width)


class SimCol3DGroundTruth(NumberedGroundTruth):
    """Depth pngs and Unity poses of one SimCol3D sequence, in endopipe's conventions."""

    dataset = NAME
    kind = GT_KIND
    title = "SimCol3D"
    frame_pattern = FRAME
    depth_pattern = DEPTH
    decode_depth = staticmethod(decode_depth)

    def has_poses(self) -> bool:
        return all(p.is_file() for p in pose_files(self.dir))

    def poses(self) -> list[np.ndarray]:
        if not self.has_poses():
            return []
        pos_file, rot_file = pose_files(self.dir)
        positions, quats = _read_rows(pos_file, 3), _read_rows(rot_file, 4)
        if len(positions) != len(quats):
            raise InputError(f"{pos_file} and {rot_file} hold different numbers of poses")
        if self.numbers and max(self.numbers) >= len(positions):
            raise InputError(
                f"{pos_file} has {len(positions)} poses; frames are numbered up to "
                f"{max(self.numbers)}"
            )
        return [unity_to_opencv(positions[n], quats[n]) for n in self.numbers]


class SimCol3DSource(ImageListSource):
    kind = NAME
    truth = SimCol3DGroundTruth


def open_sequence(path: Path, intrinsics: Camera | None = None) -> SimCol3DSource:
    path = Path(path)
    frames = numbered(path, FRAME)
    if not frames:
        raise InputError(f"{path} is not a SimCol3D sequence ({LAYOUT})")
    intrinsics = intrinsics or read_intrinsics(path, frames[0][1])
    has_gt = bool(numbered(path, DEPTH)) or all(p.is_file() for p in pose_files(path))
    return SimCol3DSource(path, [f for _, f in frames], intrinsics, path if has_gt else None)


def ground_truth(path: Path) -> SimCol3DGroundTruth:
    return SimCol3DGroundTruth(path)
