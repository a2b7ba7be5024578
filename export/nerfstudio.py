"""nerfstudio: `transforms.json`, `images/`, `masks/`, `depth/` and `sparse_pc.ply`.

transforms.json is written by the project's one writer (stages.io.transforms_json): OpenGL
camera axes (x right, y up, z back, i.e. endopipe's OpenCV c2w with its y and z axes negated),
the principal point in nerfstudio's pixel-edge convention (OpenCV + 0.5) and the lens as
nerfstudio reads it: camera_model OPENCV with k1, k2, p1, p2 (k3 when set) or OPENCV_FISHEYE with
k1..k4. Masks: 255 = use (nerfstudio's meaning too). With 05_depth, `depth/<index>.npy` +
`depth_file_path` per frame: z-depth x 1000 in the units of the poses, because nerfstudio
multiplies depth by `depth_unit_scale_factor` (default 1e-3, "millimetres to metres") to bring it
into the units of the poses. The poses are those the depth was rendered at (refined by the NeRF
when it refined them). With 02_poses/points.ply also `sparse_pc.ply` + `ply_file_path`
(splatfacto's initial points).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from endopipe.export.case import CaseExport, ExportResult, need_images, place
from endopipe.stages.io.transforms_json import TransformsEntry, write_transforms_json

#: nerfstudio divides depth files by 1000 by default (depth_unit_scale_factor = 1e-3).
NERFSTUDIO_DEPTH_FACTOR = 1000.0


def write_nerfstudio(case: CaseExport, out: Path, *, symlink: bool = False) -> ExportResult:
    need_images(case)
    notes: list[str] = []
    entries, written = [], 0
    for f in case.frames:
        name = f"{f.index:06d}.png"
        place(f.image, out / "images" / name, symlink)  # type: ignore[arg-type]
        mask = None
        if f.mask is not None:
            place(f.mask, out / "masks" / name, symlink)
            mask = f"masks/{name}"
        depth = None
        if f.has_depth:
            (out / "depth").mkdir(exist_ok=True)
            d = case.depth(f).astype(np.float32) * NERFSTUDIO_DEPTH_FACTOR
            np.save(out / "depth" / f"{f.index:06d}.npy", d)
            depth = f"depth/{f.index:06d}.npy"
            written += 1
        entries.append(TransformsEntry(f"images/{name}", mask, f.c2w, depth))
    about: dict = {
        "units": case.units,
        "metric": case.metric,
        "convention": "transform_matrix: OpenGL camera-to-world (x right, y up, z back)",
        "poses": case.poses_source,
    }
    extra: dict = {"endopipe": about}
    if case.poses.points_path.is_file():
        shutil.copy2(case.poses.points_path, out / "sparse_pc.ply")
        extra["ply_file_path"] = "sparse_pc.ply"
    if written:
        about["depth"] = (
            f"z-depth x {NERFSTUDIO_DEPTH_FACTOR:g} in {case.units}; nerfstudio's default "
            "depth_unit_scale_factor (1e-3) brings it back to the units of the poses"
        )
        if written < len(case.frames):
            notes.append(f"depth for {written} of {len(case.frames)} frames")
    else:
        notes.append("no 05_depth: transforms.json without depth_file_path")
    write_transforms_json(out / "transforms.json", case.intrinsics, entries, extra=extra)
    if case.intrinsics.distorted:
        k = case.intrinsics
        notes.append(f"lens: {k.model} {k.dist} in transforms.json (nerfstudio undistorts with it)")
    if case.refined:
        notes.append("poses refined by the NeRF: those the depth maps were rendered at")
    return ExportResult("nerfstudio", out, len(case.frames), ["transforms.json"], notes)
