"""`endopipe run INPUT --right FOLDER --baseline-mm B`: a user's rectified right frames as the
input's stereo pairs, so the stereo path (ingest's matcher, the poses' metric scale, the field's
depth rays, the stereo baseline in the scores) runs as it does for Hamlyn's image02/.

Matched to the left frames by the number in their file names (a video's frame i: the i-th right
image in number order). Everything is checked here, from the image headers, before anything is
written: a refused rig is one line, never a half-written case."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from endopipe.pipeline.cache import digest_path, digest_text
from endopipe.pipeline.errors import InputError
from endopipe.stages.io.images import (
    CROP_TOLERANCE_PX,
    IMAGE_SUFFIXES,
    crop_offset,
    header_sizes,
)
from endopipe.stages.io.numbered import by_source_index, numbered_files
from endopipe.stages.io.stereo_pairs import BASELINE_RANGE_MM, StereoPairs

SOURCE = "--right"


def check_baseline(baseline_mm: float | None) -> float:
    """The baseline a user gave, in mm: required, and in the range of an endoscope's rig."""
    if baseline_mm is None:
        raise InputError(
            "--right needs --baseline-mm B: the distance between the two eyes in mm (a baseline "
            "is never guessed)"
        )
    lo, hi = BASELINE_RANGE_MM
    if not lo <= baseline_mm <= hi:
        raise InputError(
            f"--baseline-mm {baseline_mm:g} is outside {lo:g}-{hi:g} mm; give the distance "
            "between the eyes in millimetres (a stereo endoscope's is about 4-6)"
        )
    return float(baseline_mm)


def right_folder_pairs(
    folder: Path,
    baseline_mm: float,
    numbers: list[int] | None,
    count: int | None,
    size: tuple[int, int],
) -> StereoPairs:
    """The right images of `folder` by the left frames' source_index (`numbers`: the number
    each left file carries, None: by position among `count` frames), each `size` (width,
    height) or a pixel or two larger (cropped, centred)."""
    folder = Path(folder).expanduser().resolve()
    files = by_source_index(numbered_files(folder, IMAGE_SUFFIXES, "--right"), numbers, count)
    if not files:
        how = "the numbers in the left frames' names" if numbers is not None else "position"
        raise InputError(
            f"--right {folder}: no right image matches a frame (matched by {how}); name each "
            "right image with its left frame's number"
        )
    for path, got in header_sizes(list(files.values())):
        extra = (got[0] - size[0], got[1] - size[1])
        if not (0 <= min(extra) and max(extra) <= CROP_TOLERANCE_PX):
            raise InputError(
                f"right image {path} is {got[0]}x{got[1]} but the left frames are "
                f"{size[0]}x{size[1]}; a rectified pair has one size"
            )

    def right(source_index: int) -> np.ndarray | None:
        file = files.get(source_index)
        return None if file is None else read_right(file, size)

    identity = digest_text("|".join(f"{i}:{digest_path(p)}" for i, p in sorted(files.items())))
    return StereoPairs(right, baseline_mm, f"{SOURCE} {folder}", identity)


def read_right(path: Path, size: tuple[int, int]) -> np.ndarray:
    """A right image as RGB at the left frames' size, cropped centred when a pixel or two
    larger (checked from its header when the pairs were made)."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise InputError(f"cannot read right image {path}; remove it or replace it")
    if bgr.shape[1::-1] != size:
        x0, y0 = crop_offset(bgr.shape[1::-1], size)
        bgr = bgr[y0 : y0 + size[1], x0 : x0 + size[0]]
    if bgr.shape[1::-1] != size:
        raise InputError(
            f"right image {path} is {bgr.shape[1]}x{bgr.shape[0]} but the left frames are "
            f"{size[0]}x{size[1]}; a rectified pair has one size"
        )
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
