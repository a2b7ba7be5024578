"""Open what the user gave us (a video, an image folder, an endopipe case folder) as frames.

Every problem with the input becomes one InputError line that names it and what to do.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import av
import cv2
import numpy as np

from endopipe.pipeline.cache import digest_path, digest_text
from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera

VIDEO_SUFFIXES = {".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg"}
IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}
HINT = "give a video (mp4, avi, mov, mkv), a folder of images, or an endopipe case folder"
#: Readers open_input can be told to use (`endopipe batch --format`); "auto" detects.
FORMATS = ("auto", "case", "video", "images", "hamlyn", "c3vd", "simcol3d", "c3vd_preview")


@dataclass
class Frame:
    source_index: int
    time_s: float | None
    rgb: np.ndarray  # HxWx3 uint8


def natural_key(path: Path) -> tuple:
    """Sort frame_2 before frame_10 (zero padding varies between datasets)."""
    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name))


def list_images(folder: Path) -> list[Path]:
    return sorted(
        (p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()),
        key=natural_key,
    )


class InputSource:
    """Frames plus whatever the input says about intrinsics and ground truth."""

    kind: str = "video"

    def __init__(self, path: Path, intrinsics: Camera | None, gt_dir: Path | None) -> None:
        self.path = path
        self.intrinsics = intrinsics
        self.gt_dir = gt_dir

    def frames(self) -> Iterator[Frame]:  # pragma: no cover - abstract
        raise NotImplementedError

    def frame_count(self) -> int | None:
        return None

    def digest(self) -> str:
        parts = [digest_path(self.path)]
        if self.intrinsics is not None:
            parts.append(self.intrinsics.model_dump_json())
        return digest_text("|".join(parts))

    def ground_truth(self):  # -> stages.io.ground_truth.GroundTruthSource | None
        """The input's ground truth for evaluation (None when it has none)."""
        if self.gt_dir is None:
            return None
        from endopipe.stages.io.ground_truth import open_ground_truth

        return open_ground_truth(self.gt_dir)


class VideoSource(InputSource):
    kind = "video"

    def __init__(self, path: Path, intrinsics: Camera | None, gt_dir: Path | None) -> None:
        super().__init__(path, intrinsics, gt_dir)
        self._probe()

    def _open(self) -> av.container.InputContainer:
        try:
            container = av.open(str(self.path))
        except (av.FFmpegError, UnicodeDecodeError, OSError) as e:
            raise InputError(
                f"cannot read {self.path} as a video ({_short(e)}); is the file complete? {HINT}"
            ) from None
        if not container.streams.video:
            container.close()
            raise InputError(f"{self.path} has no video stream; {HINT}")
        return container

    def _probe(self) -> None:
        container = self._open()
        stream = container.streams.video[0]
        self.fps = float(stream.average_rate or stream.guessed_rate or 25.0)
        self._declared = int(stream.frames or 0)
        container.close()

    def frame_count(self) -> int | None:
        return self._declared or None

    def frames(self) -> Iterator[Frame]:
        container = self._open()
        index = 0
        try:
            for frame in container.decode(video=0):
                t = float(frame.time) if frame.time is not None else index / self.fps
                yield Frame(index, t, frame.to_ndarray(format="rgb24"))
                index += 1
        except av.FFmpegError as e:
            raise InputError(
                f"video {self.path} is damaged after frame {index} ({_short(e)}); "
                "re-export it or trim it with --set ingest.end_s=..."
            ) from None
        finally:
            container.close()
        if self._declared and index < self._declared * 0.9:
            raise InputError(
                f"video {self.path} is truncated: its header declares {self._declared} frames "
                f"but only {index} decode; re-export or re-download it"
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

    def digest(self) -> str:
        """Only the frames (and reader, intrinsics) make the ingest key: not the whole folder."""
        h = [self.kind]
        for f in self.files:
            h.append(f"{f.relative_to(self.path)}:{digest_path(f)}")
        if self.intrinsics is not None:
            h.append(self.intrinsics.model_dump_json())
        return digest_text("|".join(h))


#: Keys that look like lens distortion but are not endopipe's (`dist` with `model`): refused,
#: never dropped in silence.
DISTORTION_LIKE = re.compile(r"^(k\d|p\d|d|dist.+|distortion.*|.*coeff.*)$", re.IGNORECASE)


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
    from PIL import Image, UnidentifiedImageError

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


def load_intrinsics_file(path: Path) -> Camera:
    if not path.is_file():
        raise InputError(f"intrinsics file not found: {path}")
    _refuse_unread_distortion(path)
    try:
        return Camera.load(path)
    except ValueError as e:
        raise InputError(
            f"intrinsics file {path} is not valid ({_invalid_fields(e)}); "
            "it needs width, height, fx, fy, cx, cy"
        ) from None


def _invalid_fields(e: ValueError) -> str:
    """Each wrong field by name and value (`fx: must be > 0, got -500`), not pydantic's
    "2 validation errors for Camera"; other errors (bad JSON) as their first line."""
    errors = getattr(e, "errors", None)
    if not callable(errors):
        return _short(e)
    parts = []
    for err in errors(include_url=False):
        where = ".".join(str(x) for x in err["loc"])
        if not where:  # a check across fields (the lens model and its coefficients)
            parts.append(_plain(err["msg"]))
        elif err["type"] == "missing":
            parts.append(f"{where} is missing")
        else:
            parts.append(f"{where}: {_plain(err['msg'])}, got {err['input']!r}")
    return "; ".join(parts)


def _plain(msg: str) -> str:
    """pydantic's wording, shorter: "Input should be greater than 0" -> "must be > 0"."""
    for long, short in (
        ("Input should be greater than or equal to", "must be >="),
        ("Input should be greater than", "must be >"),
        ("Input should be", "must be"),
        ("Value error, ", ""),
    ):
        msg = msg.replace(long, short)
    return msg


def _refuse_unread_distortion(path: Path) -> None:
    """A distortion under a name endopipe does not read would be ignored: say so instead."""
    try:
        data = json.loads(path.read_text())
    except (ValueError, OSError):
        return  # Camera.load says what is wrong with the file
    if not isinstance(data, dict):
        return
    unread = [k for k in data if k not in Camera.model_fields and DISTORTION_LIKE.match(k)]
    if unread:
        raise InputError(
            f"intrinsics file {path} has {', '.join(unread)}, which endopipe does not read; give "
            'the lens distortion as "dist" (k1, k2, p1, p2 and k3 for "model": "opencv", or '
            'k1 to k4 for "model": "fisheye")'
        )


def open_input(
    path: Path, intrinsics_file: Path | None = None, format: str | None = None
) -> InputSource:
    """Pick the reader for a path, checking it is usable before anything is written.

    `format` (one of FORMATS) overrides detection; datasets (Hamlyn, C3VD, SimCol3D) are
    read in place by the readers of stages/io/datasets.py.
    """
    path = Path(path).expanduser()
    if not path.exists():
        raise InputError(f"input not found: {path}; {HINT}")
    fmt = format or "auto"
    if fmt not in FORMATS:
        raise InputError(f"unknown input format '{fmt}'; formats: {', '.join(FORMATS)}")
    intrinsics = load_intrinsics_file(intrinsics_file) if intrinsics_file else None
    case_dir = _case_folder_of(path)
    if fmt == "auto" and case_dir is None and path.is_dir():
        from endopipe.stages.io.datasets import detect_dataset

        fmt = detect_dataset(path) or "auto"
    if fmt not in ("auto", "case", "video", "images"):
        from endopipe.stages.io.datasets import open_dataset

        return open_dataset(path, fmt, intrinsics)
    if fmt == "case" and case_dir is None:
        raise InputError(
            f"{path} is not an endopipe case folder (video.mp4 or frames/, with intrinsics.json "
            "and/or gt/)"
        )
    if fmt in ("video", "images"):
        if (fmt == "images") != path.is_dir():
            what = "a folder of images" if fmt == "images" else "a video file"
            raise InputError(f"{path} is not {what} (--format {fmt})")
        case_dir = None
    gt_dir = None
    if case_dir is not None:
        if intrinsics is None and (case_dir / "intrinsics.json").is_file():
            intrinsics = load_intrinsics_file(case_dir / "intrinsics.json")
        # Absolute, like a data set's: gt_dir lands in case.json and frames.json.
        gt_dir = (case_dir / "gt").resolve() if (case_dir / "gt").is_dir() else None
        if path.is_dir():
            path = case_dir / "frames" if (case_dir / "frames").is_dir() else case_dir / "video.mp4"
    if path.is_dir():
        source: InputSource = ImageFolderSource(path, intrinsics, gt_dir)
    elif path.suffix.lower() in IMAGE_SUFFIXES:
        raise InputError(f"{path} is a single image; {HINT}")
    else:
        if path.stat().st_size == 0:
            raise InputError(f"input file {path} is empty (0 bytes); {HINT}")
        if path.suffix.lower() not in VIDEO_SUFFIXES:
            raise InputError(f"{path} is not a video file ({path.suffix or 'no suffix'}); {HINT}")
        source = VideoSource(path, intrinsics, gt_dir)
    if case_dir is not None:
        source.kind = "case"
    return source


def _case_folder_of(path: Path) -> Path | None:
    """An endopipe case folder (DESIGN §5): video.mp4 or frames/, with intrinsics.json and/or
    gt/. Without intrinsics.json COLMAP estimates the camera, as for a plain video, and gt/ is
    still evaluated: refusing the folder would make a user drop their ground truth."""
    folder = path if path.is_dir() else path.parent
    has_media = (folder / "video.mp4").is_file() or (folder / "frames").is_dir()
    if _has_case_files(folder) and has_media:
        if path.is_dir() or path.name == "video.mp4" or path.parent.name == "frames":
            return folder
    if path.is_dir() and path.name == "frames" and _has_case_files(path.parent):
        return path.parent
    return None


def _has_case_files(folder: Path) -> bool:
    return (folder / "intrinsics.json").is_file() or (folder / "gt").is_dir()


def _short(e: BaseException) -> str:
    text = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    return text[:160]
