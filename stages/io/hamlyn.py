"""Hamlyn, rectified: read in place, nothing copied, in the layouts users download.

```
hamlyn_data/                     the rectified release
  rectifiedNN/                   (or rectifiedNN/rectifiedNN/, as its zip files unpack)
    image01/0000000000.jpg ...   left images (endopipe's frames)
    image02/0000000000.jpg ...   right images, rectified with the left: the input's stereo
    depth01/0000000000.png ...   uint16 depth in mm from a stereo network: PSEUDO ground truth
    intrinsics.txt               optional here: the rectified left camera (3x3 or 3x4)
  calibration/NN/intrinsics.txt  the rectified camera matrix (3x3; 3x4 read as its 3x3 part)
  calibration/NN/extrinsics.txt  [R | t] of the right camera (3x4, or 4x4), t in mm:
                                 the baseline is |t|

rectifiedNN/                     the release with Endo-Depth-and-Motion (EDaM)
  color/0000000000.jpg ...       left images
  depth/0000000000.png ...       uint16 depth in mm from its stereo network
  intrinsic/intrinsic_color.txt  4x4 (ScanNet's layout; its 3x3 part is the camera)
  intrinsics.txt                 accepted instead (older copies of the EDaM folder)
```

Calibration is looked for beside the images first (`intrinsics.txt`, `extrinsics.txt`: what
`endopipe synth --layout hamlyn` writes), then in the release's `calibration/NN/` next to the
sequence (NN: the number in the sequence folder's name). The right views become the input's
`StereoPairs` only with a baseline: without `extrinsics.txt` the sequence is monocular.

No poses. The depth comes from a stereo network, not a measurement, so it is labelled
`gt_kind: "pseudo"` everywhere it is used; the network saturates at 300 mm, so a value at that
ceiling says "farther than the network reaches", not a depth: it reads as unknown (0). A
synthetic sequence written in these layouts keeps its exact `gt/` beside them, read instead.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from endopipe.pipeline.cache import digest_path, digest_text
from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.frame_truth import PerFrameGroundTruth
from endopipe.stages.io.ground_truth import GroundTruthSource, holds_case_truth, open_case_truth
from endopipe.stages.io.images import ImageListSource, list_images
from endopipe.stages.io.name_numbers import file_number
from endopipe.stages.io.stereo_pairs import BASELINE_RANGE_MM, StereoPairs

NAME = "hamlyn"
LAYOUT = (
    "rectifiedNN/ with image01/*.jpg (left), image02/*.jpg (right), depth01/*.png (mm) and "
    "intrinsics.txt or the release's calibration/NN/; or Endo-Depth-and-Motion's color/*.jpg, "
    "depth/*.png (mm), intrinsic/intrinsic_color.txt (or intrinsics.txt)"
)
GT_KIND = "pseudo"
#: The stereo network's saturation depth (Endo-Depth-and-Motion's README): values at or above it
#: are not depths.
CEILING_MM = 300.0
INTRINSICS = "intrinsics.txt"
EXTRINSICS = "extrinsics.txt"
EDAM_INTRINSICS = "intrinsic/intrinsic_color.txt"
#: A right image at most this many pixels larger than the left frames is cropped, centred, as
#: the image readers crop frames of one camera that differ by a pixel or two.
CROP_PX = 2


@dataclass(frozen=True)
class Folders:
    """One layout's folder names: left images, depth, right images (None: monocular)."""

    images: str
    depth: str
    right: str | None


#: The layouts, in detection order. A folder of images named color/ is common, so that layout
#: also needs its intrinsics file to be taken for Hamlyn.
LAYOUTS = (Folders("image01", "depth01", "image02"), Folders("color", "depth", None))


def folders(path: Path) -> Folders | None:
    """The layout the sequence folder `path` has, or None."""
    for layout in LAYOUTS:
        edam = layout.images == "color"
        if edam and not any((path / f).is_file() for f in (INTRINSICS, EDAM_INTRINSICS)):
            continue
        if (path / layout.images).is_dir() and list_images(path / layout.images):
            return layout
    return None


def sequence_folder(path: Path) -> Path | None:
    """The folder holding the images: `path`, or `path/<its name>` (the release's zip files
    unpack rectifiedNN.zip into rectifiedNN/rectifiedNN/); None when neither is a sequence."""
    path = Path(path)
    if not path.is_dir():
        return None
    for seq in (path, path / path.name):
        if seq.is_dir() and folders(seq) is not None:
            return seq
    return None


def is_sequence(path: Path) -> bool:
    return sequence_folder(Path(path)) is not None


def matched(frames: list[Path], files: list[Path]) -> list[Path | None]:
    """Each frame's file in `files` (depth, right image): the one with its number when every
    file has its own (zero padding may differ), else the i-th file for frame i."""
    by_number = {file_number(f): f for f in files}
    if None not in by_number and len(by_number) == len(files):
        return [by_number.get(file_number(f)) for f in frames]
    return [files[i] if i < len(files) else None for i in range(len(frames))]


# ------------------------------------------------------------------------------ calibration


def calibration_file(seq: Path, name: str) -> Path | None:
    """`name` beside the images, above them in a nested copy, or in the release's
    calibration/NN/ (or calibration/rectifiedNN/) of a folder above the sequence."""
    seq = Path(seq)
    places = [seq]
    if seq.parent.name == seq.name:  # rectifiedNN/rectifiedNN/
        places.append(seq.parent)
    number = re.search(r"(\d+)$", seq.name)
    keys = [seq.name] + ([number.group(1), str(int(number.group(1)))] if number else [])
    for above in list(seq.parents)[:3]:
        places += [above / "calibration" / key for key in keys]
    return next((p / name for p in places if (p / name).is_file()), None)


def numbers_in(path: Path) -> np.ndarray:
    """Every number in a small text file (commas or spaces between them)."""
    try:
        return np.array(path.read_text().replace(",", " ").split(), dtype=np.float64)
    except (OSError, ValueError):
        raise InputError(f"{path} must hold a matrix of numbers") from None


def read_intrinsics(seq: Path, first_frame: Path) -> Camera | None:
    """The rectified left camera: intrinsics.txt (3x3, or a 3x4 projection) beside the images
    or in calibration/NN/, else EDaM's intrinsic/intrinsic_color.txt (4x4); the 3x3 part, at
    the first frame's size (the files hold none). None when no file is there."""
    path = calibration_file(seq, INTRINSICS)
    if path is None and (seq / EDAM_INTRINSICS).is_file():
        path = seq / EDAM_INTRINSICS
    if path is None:
        return None
    values = numbers_in(path)
    shapes = {9: (3, 3), 12: (3, 4), 16: (4, 4)}
    if values.size not in shapes:
        raise InputError(f"{path} holds {values.size} numbers; expected a 3x3, 3x4 or 4x4 matrix")
    K = values.reshape(shapes[values.size])[:3, :3]
    image = cv2.imread(str(first_frame), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"cannot read image {first_frame}; remove it or replace it")
    h, w = image.shape[:2]
    return Camera(width=w, height=h, fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2])


def read_baseline_mm(path: Path) -> float:
    """extrinsics.txt: the right camera's [R | t] (3x4, or 4x4 with its last row), t in mm;
    rectification turns the rig but keeps the distance between the eyes, |t|."""
    values = numbers_in(path)
    if values.size not in (12, 16):
        raise InputError(
            f"{path} holds {values.size} numbers; expected the right camera's [R | t] (3x4 or "
            "4x4, t in mm)"
        )
    baseline = float(np.linalg.norm(values.reshape(-1, 4)[:3, 3]))
    lo, hi = BASELINE_RANGE_MM
    if not lo <= baseline <= hi:
        raise InputError(
            f"{path} gives a stereo baseline of {baseline:g} mm, outside {lo:g}-{hi:g} mm; its "
            "translation must be in millimetres (Hamlyn's is about 5)"
        )
    return baseline


# ------------------------------------------------------------------------------ right views


def stereo_pairs(
    seq: Path, frames: list[Path], layout: Folders, size: tuple[int, int] | None = None
) -> StereoPairs | None:
    """The right images by source_index, with the baseline; None when the layout has no right
    folder, it is empty, or no extrinsics give the baseline (a baseline is never guessed).
    `size` (width, height): the frames' size as read (the first frame's when None)."""
    right_dir = seq / layout.right if layout.right else None
    if right_dir is None or not right_dir.is_dir():
        return None
    files = matched(frames, list_images(right_dir))
    extrinsics = calibration_file(seq, EXTRINSICS)
    if extrinsics is None or not any(files):
        return None
    baseline = read_baseline_mm(extrinsics)
    with Image.open(frames[0]) as first:
        size = size or first.size

    def right(source_index: int) -> np.ndarray | None:
        file = files[source_index] if 0 <= source_index < len(files) else None
        return None if file is None else read_right(file, size)

    identity = digest_text(
        "|".join(f"{f.name}:{digest_path(f)}" if f else "-" for f in files)
        + f"|{digest_path(extrinsics)}"
    )
    return StereoPairs(right, baseline, f"{right_dir.name}/, {extrinsics}", identity)


def read_right(path: Path, size: tuple[int, int]) -> np.ndarray:
    """A right image as RGB at the left frames' size (width, height): a rectified pair has one
    size; one a pixel or two larger is cropped, centred, as its left frame is."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise InputError(f"cannot read right image {path}; remove it or replace it")
    extra = (bgr.shape[1] - size[0], bgr.shape[0] - size[1])
    if extra != (0, 0) and 0 <= min(extra) and max(extra) <= CROP_PX:
        x0, y0 = extra[0] // 2, extra[1] // 2
        bgr = bgr[y0 : y0 + size[1], x0 : x0 + size[0]]
    if bgr.shape[1::-1] != size:
        raise InputError(
            f"right image {path} is {bgr.shape[1]}x{bgr.shape[0]} but the left images are "
            f"{size[0]}x{size[1]}; a rectified pair has one size"
        )
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


# ------------------------------------------------------------------------------ ground truth


class HamlynGroundTruth(PerFrameGroundTruth):
    """depth01/ or depth/ (uint16 mm from a stereo network: pseudo ground truth) matched to the
    left images by number; the network's 300 mm ceiling is unknown, not a depth."""

    dataset = NAME
    kind = GT_KIND
    title = "Hamlyn"

    def __init__(self, seq: Path) -> None:
        seq = sequence_folder(Path(seq)) or Path(seq)
        layout = folders(seq) or LAYOUTS[0]
        self.frames = list_images(seq / layout.images)
        depth_dir = seq / layout.depth
        files = list_images(depth_dir) if depth_dir.is_dir() else []
        super().__init__(seq, matched(self.frames, files), len(files))

    def decode_depth(self, raw: np.ndarray) -> np.ndarray:
        depth = raw.astype(np.float32)  # already millimetres; 0 = no stereo match
        depth[depth >= CEILING_MM] = 0.0  # saturated: farther than the network reaches
        return depth


class HamlynSource(ImageListSource):
    kind = NAME
    truth = None  # ground_truth() below: a synthetic sequence's gt/ first

    def ground_truth(self) -> GroundTruthSource | None:
        return ground_truth(self.gt_dir) if self.gt_dir is not None else None


def open_sequence(path: Path, intrinsics: Camera | None = None) -> HamlynSource:
    seq = sequence_folder(Path(path))
    layout = folders(seq) if seq is not None else None
    if seq is None or layout is None:
        raise InputError(f"{path} is not a Hamlyn rectified sequence ({LAYOUT})")
    files = list_images(seq / layout.images)
    intrinsics = intrinsics or read_intrinsics(seq, files[0])
    has_gt = (seq / layout.depth).is_dir() or holds_case_truth(seq / "gt")
    source = HamlynSource(seq, files, intrinsics, seq if has_gt else None)
    # The frames' size as read: a pixel or two under some files' when the reader crops them.
    source.stereo = stereo_pairs(seq, files, layout, getattr(source, "size", None))
    return source


def ground_truth(path: Path) -> GroundTruthSource:
    """A synthetic sequence's exact gt/ when it is there, else the data set's pseudo depth."""
    seq = sequence_folder(Path(path)) or Path(path)
    if holds_case_truth(seq / "gt"):
        return open_case_truth(seq / "gt")
    return HamlynGroundTruth(seq)
