"""SCARED (MICCAI EndoVis 2019) keyframes, read in place: the left eye rectified, the right eye
as `source.stereo`, the kinematics as known poses, the keyframe's depth as truth.

```
keyframe_1/
  endoscope_calibration.yaml     OpenCV FileStorage: M1 (or K1), D1, M2 (or K2), D2, R, T (mm)
  left_depth_map.tiff            float32 x, y, z (mm) of each left pixel, unrectified; z = 0: none
  data/rgb.mp4                   left over right, each eye a frame's upper and lower half
  data/frame_data/frame_dataNNNNNN.json   "camera-pose": the left camera's 4x4 per frame
  Left_Image.png, Right_Image.png  the keyframe's two eyes, unrectified
```

As read by dimitrisPs/scared_toolkit (scaredtk/calibrator.py: the yaml's keys; scaredtk/io.py:
the stacked video, "camera-pose", the 3-channel tiff with z = 0 unknown). A video whose frames
are wider than tall is one eye only (no right view). The frames are rectified with
cv2.stereoRectify (alpha 0: no black border); the input's intrinsics are P1's pinhole, the
truth's points are turned by R1 and projected by P1 (nearest point per pixel), and the known
poses are the left camera turned the same way. The keyframe's depth is the video's first frame
(the toolkit's interpolated sequences start at it).

A keyframe folder without its video (SCARED's unit of evaluation: one left image, one right, a
truth) is read as one stereo pair: one frame, its right eye, the same rectification.

"camera-pose" is read as camera-to-world in the file's units: public loaders disagree on its
direction and units (some invert it, some scale it by 1000), so it is kept as known poses, not
ground truth, and nothing is scored against it.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np

from endopipe.pipeline.cache import digest_path, digest_text
from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.ground_truth import GroundTruthSource, holds_case_truth, open_case_truth
from endopipe.stages.io.input_source import Frame, InputSource
from endopipe.stages.io.messages import short_reason
from endopipe.stages.io.stereo_pairs import StereoPairs
from endopipe.stages.io.stereo_rig import (
    Rig,
    StackedVideo,
    eye_size,
    fitted_to_eyes,
    own_calibration_only,
    video_size,
)

NAME = "scared"
LAYOUT = (
    "endoscope_calibration.yaml with data/rgb.mp4 (left over right) and data/frame_data/*.json, "
    "or with Left_Image.png and Right_Image.png (one keyframe)"
)
GT_KIND = "exact"
CALIBRATION = "endoscope_calibration.yaml"
VIDEO = "data/rgb.mp4"
FRAME_DATA = "data/frame_data"
KEYFRAME_DEPTH = "left_depth_map.tiff"
LEFT_IMAGE, RIGHT_IMAGE = "Left_Image.png", "Right_Image.png"
FRAME_JSON = re.compile(r"^frame_data(\d+)\.json$")


def is_sequence(path: Path) -> bool:
    path = Path(path)
    return (path / CALIBRATION).is_file() and ((path / VIDEO).is_file() or is_keyframe(path))


def is_keyframe(path: Path) -> bool:
    """One stereo pair without its video: the keyframe's two images alone."""
    path = Path(path)
    both = (path / LEFT_IMAGE).is_file() and (path / RIGHT_IMAGE).is_file()
    return both and not (path / VIDEO).is_file()


def read_calibration(path: Path, size: tuple[int, int]) -> Rig:
    """endoscope_calibration.yaml for eyes of `size` (width, height); one InputError line."""
    file = Path(path) / CALIBRATION
    fs = cv2.FileStorage(str(file), cv2.FILE_STORAGE_READ)
    try:
        if not fs.isOpened():
            raise InputError(f"cannot read {file} as OpenCV FileStorage (yaml)")

        def mat(*names: str) -> np.ndarray:
            for n in names:
                m = fs.getNode(n).mat()
                if m is not None:
                    return np.asarray(m, np.float64)
            raise InputError(f"{file} has no {' or '.join(names)}; SCARED's calibration has M1, "
                             "D1, M2, D2, R and T")  # fmt: skip

        K1, D1, K2, D2 = mat("M1", "K1"), mat("D1"), mat("M2", "K2"), mat("D2")
        R, T = mat("R"), mat("T").reshape(3, 1)
    finally:
        fs.release()
    if K1.shape != (3, 3) or K2.shape != (3, 3) or R.shape != (3, 3):
        raise InputError(f"{file}: M1, M2 and R must be 3x3 matrices")
    K1, K2, said = fitted_to_eyes(K1, K2, size, str(file))
    return Rig(K1, D1.ravel(), K2, D2.ravel(), R, T, size, said)


def read_eye(file: Path) -> np.ndarray:
    """One keyframe image as RGB; one InputError line when it cannot be read."""
    bgr = cv2.imread(str(file), cv2.IMREAD_COLOR)
    if bgr is None:
        raise InputError(f"cannot read {file} as an image")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def keyframe_eyes(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The keyframe's left and right images (RGB), of one size or one InputError line."""
    left, right = read_eye(Path(path) / LEFT_IMAGE), read_eye(Path(path) / RIGHT_IMAGE)
    if left.shape != right.shape:
        raise InputError(
            f"{Path(path) / LEFT_IMAGE} is {left.shape[1]}x{left.shape[0]} but {RIGHT_IMAGE} is "
            f"{right.shape[1]}x{right.shape[0]}: a stereo pair has one size"
        )
    return left, right


def eyes_size(path: Path) -> tuple[tuple[int, int], bool]:
    """One eye's (width, height) and whether both eyes are there: from the video, else from
    the keyframe's left image."""
    if (Path(path) / VIDEO).is_file():
        return eye_size(video_size(path / VIDEO))
    left = read_eye(Path(path) / LEFT_IMAGE)
    return (left.shape[1], left.shape[0]), True


class ScaredSource(StackedVideo):
    """The rectified left eye of rgb.mp4, frame by frame."""

    kind = NAME

    def __init__(self, path: Path, rig: Rig, stacked: bool, gt_dir: Path | None) -> None:
        super().__init__(path, path / VIDEO, path / CALIBRATION, rig, stacked, gt_dir)

    def ground_truth(self) -> GroundTruthSource | None:
        return ground_truth(self.gt_dir) if self.gt_dir is not None else None


class ScaredKeyframe(InputSource):
    """A keyframe's two images alone: one rectified left frame and its right view."""

    kind = NAME

    def __init__(self, path: Path, rig: Rig, gt_dir: Path | None) -> None:
        super().__init__(path, rig.camera(), gt_dir)
        self.rig = rig

    @cached_property
    def rectified(self) -> tuple[np.ndarray, np.ndarray]:
        """Both eyes read and rectified once (ingest asks for them several times: selection,
        the rig check at their own size, the matcher); one InputError line when unreadable."""
        left, right = keyframe_eyes(self.path)
        (lx, ly), (rx, ry) = self.rig.maps
        return cv2.remap(left, lx, ly, cv2.INTER_LINEAR), cv2.remap(right, rx, ry, cv2.INTER_LINEAR)

    def frames(self) -> Iterator[Frame]:
        yield Frame(0, 0.0, self.rectified[0].copy())

    def right_view(self, source_index: int) -> np.ndarray | None:
        return self.rectified[1].copy() if source_index == 0 else None

    def frame_count(self) -> int | None:
        return 1

    def digest(self) -> str:
        parts = [self.kind, *(digest_path(self.path / f) for f in (LEFT_IMAGE, RIGHT_IMAGE))]
        parts.append(digest_path(self.path / CALIBRATION))
        return digest_text("|".join([*parts, *self.given_digests()]))

    def ground_truth(self) -> GroundTruthSource | None:
        return ground_truth(self.gt_dir) if self.gt_dir is not None else None


def read_frame_poses(path: Path) -> list[np.ndarray] | None:
    """data/frame_data/*.json's "camera-pose" by frame number; None when there are none or a
    frame's is missing."""
    folder = Path(path) / FRAME_DATA
    if not folder.is_dir():
        return None
    files = sorted(
        (int(m.group(1)), p) for p in folder.iterdir() if (m := FRAME_JSON.match(p.name))
    )
    if not files or [n for n, _ in files] != list(range(len(files))):
        return None
    poses = []
    for _, f in files:
        try:
            pose = np.asarray(json.loads(f.read_text())["camera-pose"], np.float64)
        except (OSError, ValueError, KeyError) as e:
            raise InputError(f"cannot read the camera pose in {f}: {short_reason(e)}") from None
        if pose.shape != (4, 4) or not np.isfinite(pose).all():
            raise InputError(f"{f}: camera-pose is not a finite 4x4 matrix")
        poses.append(pose)
    return poses


def open_sequence(path: Path, intrinsics: Camera | None = None) -> InputSource:
    path = Path(path)
    own_calibration_only(path, is_sequence(path), "SCARED keyframe", LAYOUT, intrinsics)
    size, stacked = eyes_size(path)
    rig = read_calibration(path, size)
    has_gt = (path / KEYFRAME_DEPTH).is_file() or holds_case_truth(path / "gt")
    gt_dir = path if has_gt else None
    source = open_pair_or_video(path, rig, stacked, gt_dir)
    source.calibration_said = rig.said
    return source


def open_pair_or_video(path: Path, rig: Rig, stacked: bool, gt_dir: Path | None) -> InputSource:
    """The keyframe's two images alone, or its video (with its poses when they are there)."""
    if is_keyframe(path):
        pair = ScaredKeyframe(path, rig, gt_dir)
        pair.rectified  # noqa: B018  (two readable images of one size, or one line now)
        pair.stereo = StereoPairs(
            right=pair.right_view,
            baseline_mm=rig.baseline_mm(),
            source=str(path / CALIBRATION),
            identity=digest_path(path / RIGHT_IMAGE),
        )
        return pair
    source = ScaredSource(path, rig, stacked, gt_dir)
    source.stereo = source.stereo_pairs()
    poses = read_frame_poses(path)
    if poses is not None:
        source.known_poses = rig.rectified_poses(poses)
        source.known_poses_from = f"{path / FRAME_DATA} (camera-pose, rectified by R1)"
    return source


class ScaredGroundTruth:
    """The keyframe's structured-light points as the first frame's z-depth (mm) in the
    rectified left camera; no poses (the kinematics are known poses, not truth)."""

    dataset = NAME
    kind = GT_KIND
    units = "mm"

    def __init__(self, path: Path) -> None:
        self.dir = Path(path)
        self.file = self.dir / KEYFRAME_DEPTH

    def has_depth(self, source_index: int) -> bool:
        return source_index == 0 and self.file.is_file()

    def depth_count(self) -> int:
        return int(self.file.is_file())

    def has_poses(self) -> bool:
        return False

    def poses(self) -> list[np.ndarray]:
        return []

    def depth(self, source_index: int) -> np.ndarray | None:
        if not self.has_depth(source_index):
            return None
        import tifffile

        try:
            xyz = np.asarray(tifffile.imread(str(self.file)), np.float64)
        except (OSError, ValueError) as e:
            raise InputError(f"cannot read SCARED depth {self.file}: {short_reason(e)}") from None
        if xyz.ndim != 3 or xyz.shape[2] != 3:
            raise InputError(f"{self.file} is not a 3-channel (x, y, z) image")
        size, _ = eyes_size(self.dir)
        rig = read_calibration(self.dir, size)
        return rectified_depth(xyz, rig)


def rectified_depth(xyz: np.ndarray, rig: Rig) -> np.ndarray:
    """Left-camera points (H, W, 3; z = 0 or nan: none) as the rectified left camera's z-depth
    (float32 mm, 0 = none), the nearest point where several land on one pixel."""
    pts = xyz.reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(1) & (pts[:, 2] > 0)]
    R1, _, P1, _ = rig.rectified
    cam = pts @ R1.T
    cam = cam[cam[:, 2] > 0]
    u = np.round(P1[0, 0] * cam[:, 0] / cam[:, 2] + P1[0, 2]).astype(np.int64)
    v = np.round(P1[1, 1] * cam[:, 1] / cam[:, 2] + P1[1, 2]).astype(np.int64)
    w, h = rig.size
    keep = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    depth = np.full(h * w, np.inf)
    np.minimum.at(depth, v[keep] * w + u[keep], cam[keep, 2])
    depth[~np.isfinite(depth)] = 0.0
    return depth.reshape(h, w).astype(np.float32)


def ground_truth(path: Path) -> GroundTruthSource:
    """A synthetic case's exact gt/ when it is there, else the keyframe's depth."""
    path = Path(path)
    if holds_case_truth(path / "gt"):
        return open_case_truth(path / "gt")
    return ScaredGroundTruth(path)
