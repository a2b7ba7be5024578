"""StereoMIS (the da Vinci stereo set of Zenodo record 8154924, v0.0.1), one sequence read in
place: the left eye rectified, the right eye as `source.stereo`, the kinematics as known poses.

```
StereoMIS_0_0_1/
  sequences.txt              "<sequence>,<stride>" per line: not read (one sequence is a case)
  P1/                        one sequence (P2_0, P2_1, ..., P3)
    <name>.mp4               left over right, each eye a frame's upper and lower half
    StereoCalibration.ini    [StereoLeft], [StereoRight]: res_x, res_y, fc_x, fc_y, cc_x, cc_y,
                             kc_0..kc_7 (OpenCV's k1 k2 p1 p2 k3 k4 k5 k6); [StereoRight] also
                             R_0..R_8 (row-major) and T_0..T_2 (the right camera from the left, mm)
    groundtruth.txt          TUM: '#' comments, then "timestamp tx ty tz qx qy qz qw" a frame (m)
    masks/NNNNNNl.png        the left eye's mask per frame, nonzero = tissue to use
    train_split.csv, test_split.csv   not read
```

As its public loaders read it (aimi-lab/robust-pose-estimator; marslicy/StereoMIS-Dataset-in-
Pytorch): the ini by configparser, the video's upper half the left eye, groundtruth.txt's rows
the video's frames in order, translation in metres. The frames are rectified as SCARED's are
(stereo_rig.py: cv2.stereoRectify, alpha 0): the input's intrinsics are P1's pinhole, the
right eye is `source.stereo` (baseline from P2). A calibration stated for another size
(res_x, res_y) than the video's eyes is scaled to them when the aspect ratio is the same, and
said (`source.calibration_said`); of another aspect ratio it is refused in one line.

groundtruth.txt is the camera's pose from the robot's kinematics: each row read as the left
camera's c2w (rotation from the quaternion, x y z w; translation m -> mm), turned by R1 into
the rectified camera. The kinematics' camera frame is not verified to be OpenCV's (x right,
y down, z forward), nor its hand-eye calibration, so these are known poses, not ground truth:
nothing is scored against them. StereoMIS ships no depth, so there is no truth; a synthetic
sequence written in this layout (`endopipe synth --layout stereomis`) keeps its exact `gt/`
beside it, read instead.

masks/ are the input's tool masks, by the number in their names (`000012l.png` is frame 12),
read as drawn: nonzero the tissue to use, zero a tool or what else to leave out
(`ingest.tools.polarity` auto takes the data set's "black_is_tool"; another value wins). They
are applied to the rectified frame as they are (alpha-0 rectification moves a pixel by a few
at most; the public loaders do the same).
"""

from __future__ import annotations

import configparser
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.ground_truth import GroundTruthSource, holds_case_truth, open_case_truth
from endopipe.stages.io.messages import short_reason
from endopipe.stages.io.stereo_rig import (
    Rig,
    StackedVideo,
    camera_of,
    eye_size,
    matrix_of,
    own_calibration_only,
    video_size,
)
from endopipe.stages.io.tool_masks import masks_for_frames

NAME = "stereomis"
LAYOUT = (
    "StereoCalibration.ini ([StereoLeft], [StereoRight]) beside exactly one *.mp4 (left over "
    "right); optional groundtruth.txt (TUM, metres: known poses)"
)
#: StereoMIS ships no depth and its poses are not verified: no truth of its own (a synthetic
#: sequence's gt/ is exact, and says so itself).
GT_KIND = "none"
CALIBRATION = "StereoCalibration.ini"
POSES = "groundtruth.txt"
MASKS = "masks"
VIDEO_SUFFIX = ".mp4"
LEFT, RIGHT = "StereoLeft", "StereoRight"
M_TO_MM = 1000.0
#: The video's eyes may be a pixel off the stated size times the scale and keep its aspect.
ASPECT_PX = 1.0


def video_files(path: Path) -> list[Path]:
    """The sequence folder's .mp4 files (hidden ones left out)."""
    path = Path(path)
    if not path.is_dir():
        return []
    return sorted(
        p
        for p in path.iterdir()
        if p.suffix.lower() == VIDEO_SUFFIX and p.is_file() and not p.name.startswith(".")
    )


def is_sequence(path: Path) -> bool:
    """StereoCalibration.ini and exactly one video: the files, not the folder's name."""
    path = Path(path)
    return (path / CALIBRATION).is_file() and len(video_files(path)) == 1


def _number(section: configparser.SectionProxy, key: str, file: Path) -> float:
    try:
        value = float(section[key])
    except KeyError:
        raise InputError(
            f"{file} has no {key} in [{section.name}]; StereoMIS's calibration has res_x, res_y, "
            "fc_x, fc_y, cc_x, cc_y, kc_0..kc_7 in [StereoLeft] and [StereoRight], R_0..R_8 and "
            "T_0..T_2 in [StereoRight]"
        ) from None
    except ValueError:
        text = section[key]
        raise InputError(f"{file}: [{section.name}] {key} = {text!r} is not a number") from None
    if not np.isfinite(value):
        raise InputError(f"{file}: [{section.name}] {key} is not finite")
    return value


def _eye(
    ini: configparser.ConfigParser, name: str, file: Path
) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """One eye's camera matrix, its eight distortion coefficients and the size it is for."""
    s = ini[name]
    fx, fy, cx, cy = (_number(s, k, file) for k in ("fc_x", "fc_y", "cc_x", "cc_y"))
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    D = np.array([_number(s, f"kc_{i}", file) for i in range(8)])
    stated = (_number(s, "res_x", file), _number(s, "res_y", file))
    if min(stated) <= 0 or min(fx, fy) <= 0:
        raise InputError(f"{file}: [{name}] res_x, res_y, fc_x and fc_y must be positive")
    return K, D, stated


def read_calibration(path: Path, size: tuple[int, int]) -> Rig:
    """StereoCalibration.ini for eyes of `size` (width, height); one InputError line."""
    file = Path(path) / CALIBRATION
    ini = configparser.ConfigParser(interpolation=None)  # a '%' in a value is no reference
    try:
        ini.read_string(file.read_text(), source=str(file))
    except (configparser.Error, OSError, UnicodeDecodeError) as e:
        raise InputError(f"cannot read {file} as an ini file ({short_reason(e)})") from None
    for name in (LEFT, RIGHT):
        if not ini.has_section(name):
            raise InputError(f"{file} has no [{name}] section; StereoMIS's calibration has "
                             "[StereoLeft] and [StereoRight]")  # fmt: skip
    K1, D1, stated1 = _eye(ini, LEFT, file)
    K2, D2, stated2 = _eye(ini, RIGHT, file)
    R = np.array([_number(ini[RIGHT], f"R_{i}", file) for i in range(9)]).reshape(3, 3)
    T = np.array([_number(ini[RIGHT], f"T_{i}", file) for i in range(3)]).reshape(3, 1)
    K1, said = stated_for(K1, stated1, size, file)
    K2, _ = stated_for(K2, stated2, size, file)
    return Rig(K1, D1, K2, D2, R, T, size, said)


def stated_for(
    K: np.ndarray, stated: tuple[float, float], size: tuple[int, int], file: Path
) -> tuple[np.ndarray, str | None]:
    """An eye's matrix stated for images of `stated` (res_x, res_y), at the video's eye `size`:
    as given when the sizes agree, scaled (and said) when the aspect ratio does, else refused."""
    (rw, rh), (w, h) = stated, size
    if (rw, rh) == (w, h):
        return K, None
    sx, sy = w / rw, h / rh
    if abs(rh * sx - h) > ASPECT_PX:
        raise InputError(
            f"{file} states its calibration for {rw:g}x{rh:g} images but the video's eyes are "
            f"{w}x{h}, another aspect ratio: give the calibration of this video"
        )
    k: Camera = camera_of(K, (round(rw), round(rh))).zoomed(sx, sy, w, h)
    said = (
        f"{file}: the calibration is stated for {rw:g}x{rh:g} images, the video's eyes are "
        f"{w}x{h}: both eyes' matrices scaled to them (fx {k.fx:.1f}, cx {k.cx:.1f}, "
        f"cy {k.cy:.1f})"
    )
    return matrix_of(k), said


def read_known_poses(path: Path) -> list[np.ndarray] | None:
    """groundtruth.txt as the left camera's c2w per video frame (mm); None when it is not
    there or holds no pose; one InputError line when a row is not one."""
    file = Path(path) / POSES
    if not file.is_file():
        return None
    rows = []
    try:
        lines = file.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"cannot read {file} ({short_reason(e)})") from None
    for n, line in enumerate(lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        values = text.replace(",", " ").split()
        try:
            row = [float(v) for v in values]
        except ValueError:
            row = []
        if len(row) != 8 or not np.isfinite(row).all() or np.linalg.norm(row[4:]) < 1e-9:
            raise InputError(
                f"{file} line {n}: {text[:60]!r} is not a pose (TUM: 8 finite numbers, "
                "timestamp tx ty tz qx qy qz qw, a non-zero quaternion)"
            )
        rows.append(row)
    if not rows:
        return None
    arr = np.array(rows)
    rotations = Rotation.from_quat(arr[:, 4:8]).as_matrix()  # x y z w, normalised
    poses = []
    for rot, t in zip(rotations, arr[:, 1:4], strict=True):
        c2w = np.eye(4)
        c2w[:3, :3], c2w[:3, 3] = rot, t * M_TO_MM
        poses.append(c2w)
    return poses


class StereoMISSource(StackedVideo):
    """The rectified left eye of the sequence's video, frame by frame."""

    kind = NAME

    def __init__(
        self, path: Path, video: Path, rig: Rig, stacked: bool, gt_dir: Path | None
    ) -> None:
        super().__init__(path, video, path / CALIBRATION, rig, stacked, gt_dir)

    def ground_truth(self) -> GroundTruthSource | None:
        return ground_truth(self.gt_dir) if self.gt_dir is not None else None


def open_sequence(path: Path, intrinsics: Camera | None = None) -> StereoMISSource:
    path = Path(path)
    own_calibration_only(path, is_sequence(path), "StereoMIS sequence", LAYOUT, intrinsics)
    video = video_files(path)[0]
    size, stacked = eye_size(video_size(video))
    rig = read_calibration(path, size)
    gt_dir = path if holds_case_truth(path / "gt") else None
    source = StereoMISSource(path, video, rig, stacked, gt_dir)
    source.stereo = source.stereo_pairs()
    source.calibration_said = rig.said
    masks = masks_for_frames(path / MASKS, None)  # 000012l.png: frame 12
    if masks is not None:
        source.tool_masks = replace(masks, polarity="black_is_tool")  # nonzero: tissue to use
    poses = read_known_poses(path)
    if poses is not None:
        source.known_poses = rig.rectified_poses(poses)
        source.known_poses_from = f"{path / POSES} (the kinematics, m -> mm, rectified by R1)"
    return source


def ground_truth(path: Path) -> GroundTruthSource | None:
    """A synthetic sequence's exact gt/ when it is there; StereoMIS itself ships no truth."""
    path = Path(path)
    return open_case_truth(path / "gt") if holds_case_truth(path / "gt") else None
