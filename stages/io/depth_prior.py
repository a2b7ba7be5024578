"""`endopipe run INPUT --depth-prior FOLDER`: per-frame depth maps made elsewhere (a monocular
network the user ran, a stereo rig), matched to the frames by the number in their file names.

Read as they are: `.npy` (float), 16-bit `.png` or `.tif`/`.tiff` (integer or float). Their
units and scale are unknown, so they are only ever used as **relative** depth (the field's
scale-and-shift-invariant loss, a median-scaled baseline). 0, NaN and inf are unknown. Sizes
are checked from the headers when the input is opened, so a refusal comes before anything is
written."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from endopipe.pipeline.cache import digest_path, digest_text
from endopipe.pipeline.errors import InputError
from endopipe.stages.io.numbered import by_source_index, numbered_files

SUFFIXES = (".npy", ".png", ".tif", ".tiff")
#: A map whose aspect differs by more than this from the frames' is for other frames.
ASPECT_TOLERANCE = 0.02
#: Maps at most this many pixels larger than the frames are cropped, centred, as frames are.
CROP_PX = 2


@dataclass(frozen=True)
class DepthPrior:
    """The depth prior's maps by the frames' source_index."""

    folder: Path
    files: dict[int, Path] = field(default_factory=dict)

    def file(self, source_index: int) -> Path | None:
        return self.files.get(source_index)

    def read(self, source_index: int, size: tuple[int, int]) -> np.ndarray | None:
        """float32 (height, width) map of a frame at the frames' `size` (width, height) as read
        (cropped, centred, when a pixel or two larger; otherwise at its own resolution), 0 =
        unknown; None when the frame has no map."""
        path = self.files.get(source_index)
        if path is None:
            return None
        depth = read_map(path)
        extra = (depth.shape[1] - size[0], depth.shape[0] - size[1])
        if extra != (0, 0) and 0 <= min(extra) and max(extra) <= CROP_PX:
            x0, y0 = extra[0] // 2, extra[1] // 2
            depth = depth[y0 : y0 + size[1], x0 : x0 + size[0]]
        return depth

    def digest(self) -> str:
        """The maps are part of the input: a changed map re-runs ingest."""
        return digest_text(
            "prior|" + "|".join(f"{i}:{digest_path(p)}" for i, p in sorted(self.files.items()))
        )


def open_depth_prior(
    folder: Path, numbers: list[int] | None, count: int | None, size: tuple[int, int]
) -> DepthPrior:
    """The maps of `folder` by source_index (`numbers`: the number each frame's file carries;
    None: by position among `count` frames), each of the frames' aspect (`size`: width,
    height); refused in one line when none matches a frame or one is of another shape."""
    folder = Path(folder).expanduser().resolve()
    files = by_source_index(numbered_files(folder, SUFFIXES, "--depth-prior"), numbers, count)
    if not files:
        how = "the numbers in the frames' names" if numbers is not None else "position"
        raise InputError(
            f"--depth-prior {folder}: no depth map (.npy, 16-bit .png, .tiff) matches a frame "
            f"(matched by {how}); name each map with its frame's number"
        )
    for path in files.values():
        w, h = map_size(path)
        extra = (w - size[0], h - size[1])
        if 0 <= min(extra) and max(extra) <= CROP_PX:
            continue
        if abs(w / h - size[0] / size[1]) > ASPECT_TOLERANCE * size[0] / size[1]:
            raise InputError(
                f"depth prior {path} is {w}x{h} but the frames are {size[0]}x{size[1]}; a map "
                "must cover its frame (the same size, or the same shape at another resolution)"
            )
    return DepthPrior(folder, files)


def map_size(path: Path) -> tuple[int, int]:
    """(width, height) of a map from its header (a .npy's shape), refusing what is not one
    depth map."""
    if path.suffix.lower() == ".npy":
        try:
            shape = np.load(path, mmap_mode="r").shape
        except (OSError, ValueError) as e:
            raise InputError(f"cannot read depth prior {path} ({e}); replace it") from None
        shape = shape[:2] if len(shape) == 3 and shape[2] == 1 else shape
        if len(shape) != 2:
            raise InputError(
                f"depth prior {path} has shape {tuple(shape)}; expected one (height, width) map"
            )
        return int(shape[1]), int(shape[0])
    try:
        with Image.open(path) as image:
            bands, mode, size = len(image.getbands()), image.mode, image.size
    except (OSError, UnidentifiedImageError):
        raise InputError(f"cannot read depth prior {path}; replace it") from None
    if bands != 1:
        raise InputError(f"depth prior {path} has {bands} channels; expected one depth channel")
    if path.suffix.lower() == ".png" and mode not in ("I", "I;16", "I;16B", "I;16L"):
        raise InputError(
            f"depth prior {path} is an 8-bit PNG ({mode}): too coarse for depth; write 16-bit "
            "PNGs, float .npy or .tiff"
        )
    return size


def read_map(path: Path) -> np.ndarray:
    """The map as float32, 0 where it is unknown (0, negative, NaN or inf)."""
    if path.suffix.lower() == ".npy":
        depth = np.load(path)
    else:
        depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if depth is None:
            raise InputError(f"cannot read depth prior {path}; replace it")
    depth = np.asarray(depth, dtype=np.float32)
    if depth.ndim == 3:
        depth = depth[..., 0]
    return np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
