"""Which data set reader reads a folder, and the ground truth behind any `gt_dir`.

The data sets are read in place, one module each: Hamlyn ("hamlyn", rectified release), C3VD
("c3vd"), SimCol3D ("simcol3d"), C3VD v3's preview frames ("c3vd_preview"), EndoNeRF's
layout ("endonerf"), SCARED's keyframes ("scared") and StereoMIS's sequences ("stereomis").
Detection looks at the files, never at folder names, so a renamed copy is still recognised;
`--format` overrides it.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io import c3vd, c3vd_preview, endonerf, hamlyn, scared, simcol3d, stereomis
from endopipe.stages.io.ground_truth import GroundTruthSource, open_case_truth
from endopipe.stages.io.input_source import InputSource

#: Data set readers, in detection order. Each module has NAME, LAYOUT, GT_KIND,
#: is_sequence(path), open_sequence(path, intrinsics) and ground_truth(gt_dir).
READERS: dict[str, ModuleType] = {
    m.NAME: m for m in (hamlyn, c3vd, simcol3d, c3vd_preview, endonerf, scared, stereomis)
}

DESCRIPTIONS = {
    "case": "endopipe case folder (intrinsics.json + video.mp4 or frames/, optional gt/)",
    "video": "video file",
    "images": "folder of images",
    **{name: f"{name}: {m.LAYOUT}" for name, m in READERS.items()},
}


def detect_dataset(path: Path) -> str | None:
    """The data set reader for a sequence folder, or None."""
    path = Path(path)
    if not path.is_dir():
        return None
    for name, reader in READERS.items():
        if reader.is_sequence(path):
            return name
    return None


def open_dataset(path: Path, fmt: str, intrinsics: Camera | None = None) -> InputSource:
    reader = READERS.get(fmt)
    if reader is None:
        raise InputError(f"unknown data set format '{fmt}'; formats: {', '.join(READERS)}")
    if not reader.is_sequence(Path(path)):
        raise InputError(f"{path} is not a {fmt} sequence ({reader.LAYOUT})")
    return reader.open_sequence(Path(path).resolve(), intrinsics)  # gt_dir lands in case.json


def open_ground_truth(gt_dir: Path | str) -> GroundTruthSource:
    """The ground truth behind a `gt_dir` (case.json / frames.json), whatever its format: the
    one door every stage, command and report goes through (InputError when none is there)."""
    gt_dir = Path(gt_dir)
    # A data set's layout first: a Hamlyn sequence's depth/ is not an endopipe case's gt/.
    name = detect_dataset(gt_dir)
    return open_case_truth(gt_dir) if name is None else READERS[name].ground_truth(gt_dir)
