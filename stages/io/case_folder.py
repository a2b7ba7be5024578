"""Whether a path is (or lies in) an endopipe case folder (docs/formats.md)."""

from __future__ import annotations

from pathlib import Path


def case_folder_of(path: Path) -> Path | None:
    """The case folder of `path` (video.mp4 or frames/, with intrinsics.json and/or gt/), or None.

    Without intrinsics.json COLMAP estimates the camera, as for a plain video, and gt/ is still
    evaluated: refusing the folder would make a user drop their ground truth."""
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
