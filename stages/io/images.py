"""Image files as frames: a folder of images, or a data set's ordered list of them."""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import ClassVar

import cv2
from PIL import Image, UnidentifiedImageError

from endopipe.pipeline.cache import digest_path, digest_text
from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.ground_truth import GroundTruthSource
from endopipe.stages.io.input_source import Frame, InputSource
from endopipe.stages.io.messages import HINT

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}
#: Frames whose sizes differ by at most this many pixels in width and in height (Hamlyn's copies
#: hold 418- and 419-pixel-wide frames of one camera) are cropped, centred, to the smallest.
CROP_TOLERANCE_PX = 2


def natural_key(path: Path) -> tuple:
    """Sort frame_2 before frame_10 (zero padding varies between datasets)."""
    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name))


def list_images(folder: Path) -> list[Path]:
    return sorted(
        (p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()),
        key=natural_key,
    )


class ImageFolderSource(InputSource):
    kind = "images"

    def __init__(self, path: Path, intrinsics: Camera | None, gt_dir: Path | None) -> None:
        super().__init__(path, intrinsics, gt_dir)
        self.files = list_images(path)
        if not self.files:
            raise InputError(f"folder {path} holds no images (png, jpg, bmp, tif); {HINT}")
        self.size = common_size(self, self.files)

    def frame_count(self) -> int | None:
        return len(self.files)

    def frames(self) -> Iterator[Frame]:
        return read_images(self.files, self.size)


class ImageListSource(InputSource):
    """Frames from a fixed, ordered list of image files (dataset readers build on it)."""

    kind = "images"
    #: A data set reader's ground-truth class, which reads the set's files in gt_dir in place;
    #: None reads an endopipe case's gt/.
    truth: ClassVar[Callable[[Path], GroundTruthSource] | None] = None

    def __init__(
        self,
        path: Path,
        files: list[Path],
        intrinsics: Camera | None,
        gt_dir: Path | None,
    ) -> None:
        super().__init__(path, intrinsics, gt_dir)
        self.files = files
        if not self.files:
            raise InputError(f"{path} holds no frames for the {self.kind} reader; {HINT}")
        self.size = common_size(self, self.files)

    def frame_count(self) -> int | None:
        return len(self.files)

    def frames(self) -> Iterator[Frame]:
        return read_images(self.files, self.size)

    def ground_truth(self) -> GroundTruthSource | None:
        if self.truth is None or self.gt_dir is None:
            return super().ground_truth()
        return self.truth(self.gt_dir)

    def digest(self) -> str:
        """Only the frames (and reader, intrinsics) make the ingest key: not the whole folder."""
        h = [self.kind]
        for f in self.files:
            h.append(f"{f.relative_to(self.path)}:{digest_path(f)}")
        return digest_text("|".join([*h, *self.given_digests()]))


def read_images(files: list[Path], size: tuple[int, int] | None = None) -> Iterator[Frame]:
    """The images as RGB frames, in order; an unreadable one stops. `size` (width, height):
    frames a pixel or two larger are cropped to it, centred (`common_size`); without it, or
    further apart, a frame of another size stops."""
    first: tuple[Path, tuple[int, ...]] | None = None
    for i, f in enumerate(files):
        bgr = cv2.imread(str(f), cv2.IMREAD_COLOR)
        if bgr is None:
            raise InputError(f"cannot read image {f}; remove it or replace it")
        if size is not None and bgr.shape[1::-1] != size and _within(bgr.shape[1::-1], size):
            x0, y0 = crop_offset(bgr.shape[1::-1], size)
            bgr = bgr[y0 : y0 + size[1], x0 : x0 + size[0]]
        first = first or (f, bgr.shape[:2])
        if bgr.shape[:2] != first[1]:
            _refuse_mixed_sizes(first[0], first[1][::-1], f, bgr.shape[1::-1])
        yield Frame(i, None, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))


def header_sizes(files: list[Path]) -> list[tuple[Path, tuple[int, int]]]:
    """(file, (width, height)) from the image headers (Pillow reads only those); unreadable
    files are left out (read_images names them)."""
    out = []
    for f in files:
        try:
            with Image.open(f) as image:
                out.append((f, image.size))
        except (OSError, UnidentifiedImageError):
            continue
    return out


def check_one_size(files: list[Path]) -> tuple[int, int] | None:
    """The one size every frame shares, or the smallest when they differ by at most
    CROP_TOLERANCE_PX a dimension (None when no header could be read); frames further apart
    are refused: one camera at one resolution."""
    return _common(header_sizes(files))


def _common(sizes: list[tuple[Path, tuple[int, int]]]) -> tuple[int, int] | None:
    if not sizes:
        return None
    size = (min(s[0] for _, s in sizes), min(s[1] for _, s in sizes))
    ref_file, ref = min(sizes, key=lambda fs: fs[1][0] * fs[1][1])
    for f, s in sizes:
        if not _within(s, size):
            _refuse_mixed_sizes(ref_file, ref, f, s)
    return size


def common_size(source: InputSource, files: list[Path]) -> tuple[int, int] | None:
    """The frames' common size (`check_one_size`); when frames are cropped to it, one line says
    so (kept in `source.notes`, which ingest logs) and the source's intrinsics follow the crop."""
    sizes = header_sizes(files)
    size = _common(sizes)
    odd = [s for _, s in sizes if s != size]
    if size is None or not odd:
        return size
    others = ", ".join(f"{w}x{h}" for w, h in sorted(set(odd)))
    line = (
        f"{len(odd)} of {len(files)} frames are {others}, not {size[0]}x{size[1]}: cropped to "
        f"{size[0]}x{size[1]}, centred"
    )
    k = source.intrinsics
    if k is not None and (k.width, k.height) != size and _within((k.width, k.height), size):
        x0, y0 = crop_offset((k.width, k.height), size)
        source.intrinsics = k.cropped(x0, y0, *size)
        if x0 or y0:
            line += f"; the intrinsics' principal point moved by ({-x0}, {-y0}) px"
    source.notes.append(line)  # ingest says it
    return size


def crop_offset(size: tuple[int, int], to: tuple[int, int]) -> tuple[int, int]:
    """Top-left corner of the centred `to` crop of an image of `size` (width, height)."""
    return (size[0] - to[0]) // 2, (size[1] - to[1]) // 2


def _within(size: tuple[int, int], to: tuple[int, int]) -> bool:
    return 0 <= size[0] - to[0] <= CROP_TOLERANCE_PX and 0 <= size[1] - to[1] <= CROP_TOLERANCE_PX


def _refuse_mixed_sizes(a: Path, size_a: tuple, b: Path, size_b: tuple) -> None:
    raise InputError(
        f"images differ in size: {a.name} is {size_a[0]}x{size_a[1]}, {b.name} is "
        f"{size_b[0]}x{size_b[1]} (in {b.parent}); endopipe needs every frame from one camera "
        f"at one resolution (frames at most {CROP_TOLERANCE_PX} px apart are cropped): move the "
        "odd images out, or resize them all to one size"
    )
