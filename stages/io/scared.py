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
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import av
import cv2
import numpy as np

from endopipe.pipeline.cache import digest_path, digest_text
from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.calibration_check import fit_to_frames
from endopipe.stages.io.ground_truth import GroundTruthSource, holds_case_truth, open_case_truth
from endopipe.stages.io.input_source import Frame, InputSource
from endopipe.stages.io.messages import short_reason
from endopipe.stages.io.stereo_pairs import StereoPairs

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


@dataclass(frozen=True)
class Rig:
    """The calibrated pair and its rectification at one image size."""

    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    size: tuple[int, int]  # width, height of one eye
    said: str | None = None  # the calibration rescaled to this size, in one line

    @cached_property
    def rectified(self) -> tuple[np.ndarray, ...]:
        """R1, R2, P1, P2 of cv2.stereoRectify (alpha 0, principal points made equal)."""
        R1, R2, P1, P2, *_ = cv2.stereoRectify(
            self.K1, self.D1, self.K2, self.D2, self.size, self.R, self.T, alpha=0
        )
        return R1, R2, P1, P2

    @cached_property
    def maps(self) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
        R1, R2, P1, P2 = self.rectified
        left = cv2.initUndistortRectifyMap(self.K1, self.D1, R1, P1, self.size, cv2.CV_32FC1)
        right = cv2.initUndistortRectifyMap(self.K2, self.D2, R2, P2, self.size, cv2.CV_32FC1)
        return left, right

    def camera(self) -> Camera:
        P1 = self.rectified[2]
        w, h = self.size
        return Camera(width=w, height=h, fx=P1[0, 0], fy=P1[1, 1], cx=P1[0, 2], cy=P1[1, 2])

    def baseline_mm(self) -> float:
        P2 = self.rectified[3]
        return float(abs(P2[0, 3] / P2[0, 0]))


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


def fitted_to_eyes(
    K1: np.ndarray, K2: np.ndarray, size: tuple[int, int], source: str
) -> tuple[np.ndarray, np.ndarray, str | None]:
    """Both eyes' matrices checked against the images' size (calibration_check.py): stated
    for another size, both are brought to this one, and the line says so."""
    fit = fit_to_frames(_camera_of(K1, size), source)
    if fit.said is None or fit.camera.fx == K1[0, 0]:
        return K1, K2, fit.said
    factor = fit.camera.fx / K1[0, 0]
    return (
        _matrix_of(fit.camera),
        _matrix_of(_camera_of(K2, size).zoomed(factor, factor, *size)),
        fit.said,
    )


def _camera_of(K: np.ndarray, size: tuple[int, int]) -> Camera:
    return Camera(width=size[0], height=size[1], fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2])


def _matrix_of(k: Camera) -> np.ndarray:
    return np.array([[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]])


def video_size(path: Path) -> tuple[int, int]:
    """(width, height) of rgb.mp4's frames; one InputError line when it is not a video."""
    try:
        with av.open(str(Path(path) / VIDEO)) as container:
            stream = container.streams.video[0]
            return int(stream.width), int(stream.height)
    except (av.FFmpegError, IndexError, OSError) as e:
        raise InputError(f"cannot read {Path(path) / VIDEO} ({short_reason(e)})") from None


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
        return eye_size(video_size(path))
    left = read_eye(Path(path) / LEFT_IMAGE)
    return (left.shape[1], left.shape[0]), True


def eye_size(frame_size: tuple[int, int]) -> tuple[tuple[int, int], bool]:
    """One eye's (width, height) and whether the frames hold both (taller than wide)."""
    w, h = frame_size
    stacked = h > w
    return ((w, h // 2) if stacked else (w, h)), stacked


class ScaredSource(InputSource):
    """The rectified left eye of rgb.mp4, frame by frame."""

    kind = NAME

    def __init__(self, path: Path, rig: Rig, stacked: bool, gt_dir: Path | None) -> None:
        super().__init__(path, rig.camera(), gt_dir)
        self.rig, self.stacked = rig, stacked
        self.fps = 25.0

    def _eyes(self) -> Iterator[tuple[int, float | None, np.ndarray, np.ndarray | None]]:
        """(index, time, left, right or None), unrectified, in order."""
        w, h = self.rig.size
        try:
            with av.open(str(self.path / VIDEO)) as container:
                stream = container.streams.video[0]
                self.fps = float(stream.average_rate or 25.0)
                for i, frame in enumerate(container.decode(video=0)):
                    rgb = frame.to_ndarray(format="rgb24")
                    t = float(frame.time) if frame.time is not None else i / self.fps
                    yield i, t, rgb[:h, :w], (rgb[h : 2 * h, :w] if self.stacked else None)
        except av.FFmpegError as e:
            raise InputError(f"{self.path / VIDEO} is damaged ({short_reason(e)})") from None

    def frames(self) -> Iterator[Frame]:
        (mx, my), _ = self.rig.maps
        for i, t, left, _ in self._eyes():
            yield Frame(i, t, cv2.remap(left, mx, my, cv2.INTER_LINEAR))

    def right_view(self) -> RightViews:
        return RightViews(self)

    def frame_count(self) -> int | None:
        try:
            with av.open(str(self.path / VIDEO)) as container:
                return int(container.streams.video[0].frames or 0) or None
        except (av.FFmpegError, OSError):
            return None

    def digest(self) -> str:
        parts = [self.kind, digest_path(self.path / VIDEO), digest_path(self.path / CALIBRATION)]
        if self.known_poses is not None:
            parts.append(digest_text(repr([p.round(9).tolist() for p in self.known_poses])))
        return digest_text("|".join([*parts, *self.given_digests()]))

    def ground_truth(self) -> GroundTruthSource | None:
        return ground_truth(self.gt_dir) if self.gt_dir is not None else None


class RightViews:
    """The rectified right eye by source_index, decoding forward and starting again only when
    an earlier frame is asked for (a matcher walks the frames in order)."""

    def __init__(self, source: ScaredSource) -> None:
        self.source = source
        self._it: Iterator | None = None
        self._at = -1

    def __call__(self, source_index: int) -> np.ndarray | None:
        if self._it is None or source_index <= self._at:
            self._it, self._at = self.source._eyes(), -1
        for i, _, _, right in self._it:
            self._at = i
            if i == source_index:
                (mx, my) = self.source.rig.maps[1]
                return None if right is None else cv2.remap(right, mx, my, cv2.INTER_LINEAR)
        self._it = None
        return None


class ScaredKeyframe(InputSource):
    """A keyframe's two images alone: one rectified left frame and its right view."""

    kind = NAME

    def __init__(self, path: Path, rig: Rig, gt_dir: Path | None) -> None:
        super().__init__(path, rig.camera(), gt_dir)
        self.rig = rig

    def _rectified(self) -> tuple[np.ndarray, np.ndarray]:
        left, right = keyframe_eyes(self.path)
        (lx, ly), (rx, ry) = self.rig.maps
        return cv2.remap(left, lx, ly, cv2.INTER_LINEAR), cv2.remap(right, rx, ry, cv2.INTER_LINEAR)

    def frames(self) -> Iterator[Frame]:
        yield Frame(0, 0.0, self._rectified()[0])

    def right_view(self, source_index: int) -> np.ndarray | None:
        return self._rectified()[1] if source_index == 0 else None

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
    if not is_sequence(path):
        raise InputError(f"{path} is not a SCARED keyframe ({LAYOUT})")
    if intrinsics is not None:
        raise InputError(
            "SCARED's frames are rectified with its own calibration; drop --intrinsics"
        )
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
        keyframe_eyes(path)  # two readable images of one size, or one line now
        pair = ScaredKeyframe(path, rig, gt_dir)
        pair.stereo = StereoPairs(
            right=pair.right_view,
            baseline_mm=rig.baseline_mm(),
            source=str(path / CALIBRATION),
            identity=digest_path(path / RIGHT_IMAGE),
        )
        return pair
    source = ScaredSource(path, rig, stacked, gt_dir)
    if stacked:
        source.stereo = StereoPairs(
            right=source.right_view(),
            baseline_mm=rig.baseline_mm(),
            source=str(path / CALIBRATION),
            identity=digest_path(path / VIDEO),
        )
    poses = read_frame_poses(path)
    if poses is not None:
        turn = np.eye(4)
        turn[:3, :3] = rig.rectified[0].T  # the rectified camera: X_cam = R1^T X_rect
        source.known_poses = [p @ turn for p in poses]
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
