"""Open what the user gave us (a video, an image folder, an endopipe case folder, a data set
sequence) as frames, checking it is usable before anything is written.

Every problem with the input becomes one InputError line that names it and what to do.
"""

from __future__ import annotations

from pathlib import Path

from endopipe.pipeline.errors import InputError
from endopipe.stages.io.added import AddedInputs, add_inputs
from endopipe.stages.io.case_folder import case_folder_of
from endopipe.stages.io.datasets import READERS, detect_dataset, open_dataset
from endopipe.stages.io.images import IMAGE_SUFFIXES, ImageFolderSource
from endopipe.stages.io.input_source import InputSource
from endopipe.stages.io.intrinsics import load_intrinsics_file
from endopipe.stages.io.messages import HINT
from endopipe.stages.io.name_numbers import file_number
from endopipe.stages.io.tool_masks import TOOLS_DIR, ToolMasks, masks_for_frames
from endopipe.stages.io.video import VIDEO_SUFFIXES, VideoSource

#: Readers open_input can be told to use (`endopipe batch --format`); "auto" detects.
FORMATS = ("auto", "case", "video", "images", *READERS)


def open_input(
    path: Path,
    intrinsics_file: Path | None = None,
    format: str | None = None,
    added: AddedInputs | None = None,
) -> InputSource:
    """Pick the reader for a path, checking it is usable before anything is written.

    `format` (one of FORMATS) overrides detection; datasets (Hamlyn, C3VD, SimCol3D) are
    read in place by the readers of stages/io/datasets.py. `added`: the right views and depth
    prior the user gave beside the input (`--right`, `--depth-prior`), put on the source.
    """
    return add_inputs(read_input(path, intrinsics_file, format), added)


def read_input(
    path: Path, intrinsics_file: Path | None = None, format: str | None = None
) -> InputSource:
    """The input as its reader reads it."""
    path = Path(path).expanduser()
    if not path.exists():
        raise InputError(f"input not found: {path}; {HINT}")
    fmt = format or "auto"
    if fmt not in FORMATS:
        raise InputError(f"unknown input format '{fmt}'; formats: {', '.join(FORMATS)}")
    intrinsics = load_intrinsics_file(intrinsics_file) if intrinsics_file else None
    case_dir = case_folder_of(path)
    if fmt == "auto" and case_dir is None and path.is_dir():
        fmt = detect_dataset(path) or "auto"
    if fmt in READERS:
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
        source.tool_masks = case_tool_masks(case_dir, source)
    return source


def case_tool_masks(case_dir: Path, source: InputSource) -> ToolMasks | None:
    """A case folder's masks/ (255 = tool), matched by number to frames/ files, or to the
    video's frame numbers."""
    files = source.files if isinstance(source, ImageFolderSource) else None
    numbers = [file_number(f) for f in files] if files is not None else None
    return masks_for_frames(case_dir / TOOLS_DIR, numbers)
