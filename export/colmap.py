"""colmap: `sparse/0/` (a COLMAP text model) and `images/`.

The model carries the camera with its lens (COLMAP model + params) and, per image, the
world-to-camera pose of the frame's depth. 02_poses/sparse is copied as it is when it holds
those poses and this camera (COLMAP's own model, with its tracks); when the NeRF refined the
poses, pycolmap moves its images to the refined poses (its points stay where they were
triangulated, their errors recomputed); without a usable model one is written from the poses,
without tracks (empty points3D.txt), its camera as 02_poses estimated it (cameras.json's model)
when that model holds the camera at the images' size, else the smallest one that does.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from endopipe.export.case import CaseExport, ExportResult, need_images, place
from endopipe.pipeline.errors import InputError
from endopipe.stages.io.colmap_model import (
    camera_to_colmap,
    read_colmap_model,
    set_poses,
    write_text_model,
)

MODEL_FILES = ("cameras", "images", "points3D")
#: Written beside the three by COLMAP 3.12 and later (camera rigs); copied when present.
RIG_FILES = ("rigs", "frames")


def write_colmap(case: CaseExport, out: Path, *, symlink: bool = False) -> ExportResult:
    need_images(case)
    for f in case.frames:
        place(f.image, out / "images" / f.image.name, symlink)  # type: ignore[union-attr]
    sparse = out / "sparse" / "0"
    src = case.poses.sparse_dir
    c2w = {f.image.name: f.c2w for f in case.frames}  # type: ignore[union-attr]
    usable = model_complete(src) and same_camera(src, case)
    if usable and not case.refined:
        sparse.mkdir(parents=True)
        for name in (*MODEL_FILES, *RIG_FILES):
            for ext in ("txt", "bin"):
                if (src / f"{name}.{ext}").is_file():
                    shutil.copy2(src / f"{name}.{ext}", sparse / f"{name}.{ext}")
        note = "02_poses/sparse copied as it is (with its tracks, if any)"
    elif usable:
        import pycolmap

        rec = pycolmap.Reconstruction(str(src))
        moved = set_poses(rec, c2w)
        sparse.mkdir(parents=True)
        rec.write_text(str(sparse))
        note = (
            f"02_poses/sparse with {moved} image(s) at the NeRF's refined poses (its points stay "
            "where they were triangulated from the given poses)"
        )
    else:
        write_text_model(sparse, case.intrinsics, c2w, colmap_model_of(case))
        note = "sparse model written from the poses (no tracks: empty points3D.txt)"
    notes = [note, f"camera: {camera_line(case)}"]
    return ExportResult("colmap", out, len(case.frames), ["sparse/0", "images"], notes)


def model_complete(folder: Path) -> bool:
    return all(
        any((folder / f"{name}.{ext}").is_file() for ext in ("txt", "bin")) for name in MODEL_FILES
    )


def same_camera(folder: Path, case: CaseExport) -> bool:
    """The model's camera is the export's (same size and lens, to rounding): its tracks'
    pixels then hold."""
    try:
        theirs = read_colmap_model(folder).camera
    except InputError:
        return False
    ours = case.intrinsics
    if theirs is None or (theirs.width, theirs.height) != (ours.width, ours.height):
        return False
    if theirs.distorted != ours.distorted or (ours.distorted and theirs.model != ours.model):
        return False
    a, b = theirs.coefficients(), ours.coefficients()
    n = max(len(a), len(b))
    a, b = np.pad(a, (0, n - len(a))), np.pad(b, (0, n - len(b)))
    pinhole = [(c.fx, c.fy, c.cx, c.cy) for c in (theirs, ours)]
    return bool(np.allclose(*pinhole, rtol=1e-9, atol=1e-9) and np.allclose(a, b, atol=1e-12))


def colmap_model_of(case: CaseExport) -> str | None:
    """cameras.json's COLMAP model when it holds the camera at the images' size (a one-focal
    model may not, once scaled), else None: the smallest that holds it."""
    try:
        return camera_to_colmap(case.intrinsics, case.poses.file.model)[0]
    except ValueError:
        return None


def camera_line(case: CaseExport) -> str:
    name, params = camera_to_colmap(case.intrinsics, colmap_model_of(case))
    return f"{name} {' '.join(f'{p:.6g}' for p in params)}"
