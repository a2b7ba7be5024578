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
        check_one_size(self.files)

    def frame_count(self) -> int | None:
        return len(self.files)

    def frames(self) -> Iterator[Frame]:
        return read_images(self.files)


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
        check_one_size(self.files)

    def frame_count(self) -> int | None:
        return len(self.files)

    def frames(self) -> Iterator[Frame]:
        return read_images(self.files)

    def ground_truth(self) -> GroundTruthSource | None:
        if self.truth is None or self.gt_dir is None:
            return super().ground_truth()
        return self.truth(self.gt_dir)

    def digest(self) -> str:
        """Only the frames (and reader, intrinsics) make the ingest key: not the whole folder."""
        h = [self.kind]
        for f in self.files:
            h.append(f"{f.relative_to(self.path)}:{digest_path(f)}")
        if self.intrinsics is not None:
            h.append(self.intrinsics.model_dump_json())
        if self.tool_masks is not None:
            h.append(self.tool_masks.digest())
        if self.stereo is not None:
            h.append(self.stereo.digest())
        return digest_text("|".join(h))


def read_images(files: list[Path]) -> Iterator[Frame]:
    """The images as RGB frames, in order; an unreadable one or one of another size stops."""
    first: tuple[Path, tuple[int, ...]] | None = None
    for i, f in enumerate(files):
        bgr = cv2.imread(str(f), cv2.IMREAD_COLOR)
        if bgr is None:
            raise InputError(f"cannot read image {f}; remove it or replace it")
        first = first or (f, bgr.shape[:2])
        if bgr.shape[:2] != first[1]:
            _refuse_mixed_sizes(first[0], first[1][::-1], f, bgr.shape[1::-1])
        yield Frame(i, None, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))


def check_one_size(files: list[Path]) -> None:
    """All frames from one camera at one resolution, checked from the image headers (Pillow
    reads only those) before a case folder is made; unreadable files are left to read_images."""
    first: tuple[Path, tuple[int, int]] | None = None
    for f in files:
        try:
            with Image.open(f) as image:
                size = image.size
        except (OSError, UnidentifiedImageError):
            continue
        first = first or (f, size)
        if size != first[1]:
            _refuse_mixed_sizes(first[0], first[1], f, size)


def _refuse_mixed_sizes(a: Path, size_a: tuple, b: Path, size_b: tuple) -> None:
    raise InputError(
        f"images differ in size: {a.name} is {size_a[0]}x{size_a[1]}, {b.name} is "
        f"{size_b[0]}x{size_b[1]} (in {b.parent}); endopipe needs every frame from one camera "
        "at one resolution: move the odd images out, or resize them all to one size"
    )
