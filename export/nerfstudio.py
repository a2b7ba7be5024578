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

The same depth also as 16-bit PNGs (`depth_png/<index>.png`, 0 = unknown) named by
`transforms_png.json`, for nerfstudio's readers that take no .npy (before its .npy support
`get_depth_image_from_path` read only cv2 16-bit images, times depth_unit_scale_factor and the
dataparser's scale): z-depth x 1000 in the units of the poses when the deepest value fits, so
the default factor 1e-3 is right as for the .npy; else x the largest power of ten that fits,
and the notes and transforms_png.json say the factor to pass (`--depth-unit-scale-factor`).
`--resolution source` writes the input's full-size frames (pixels.py), the camera scaled to them.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np

from endopipe.export.case import CaseExport, ExportResult, need_images, place
from endopipe.export.endonerf import deepest_depth
from endopipe.export.pixels import UPSAMPLING, export_camera, frame_pixels
from endopipe.stages.io.transforms_json import TransformsEntry, write_transforms_json

#: nerfstudio divides depth files by 1000 by default (depth_unit_scale_factor = 1e-3).
NERFSTUDIO_DEPTH_FACTOR = 1000.0
#: transforms.json's twin whose frames name the 16-bit depth PNGs (readers without .npy).
PNG_TRANSFORMS = "transforms_png.json"


def png_depth_scale(deepest: float) -> float:
    """Counts per unit of the poses in the 16-bit PNGs: 1000 (nerfstudio's default
    depth_unit_scale_factor 1e-3 reads them) when the deepest value fits, else the largest power
    of ten that keeps it under 65535 (then the factor to pass is 1 / that)."""
    scale = NERFSTUDIO_DEPTH_FACTOR
    while deepest * scale > 65535 and scale > 1e-12:
        scale /= 10.0
    return scale


def write_nerfstudio(
    case: CaseExport, out: Path, *, symlink: bool = False, resolution: str = "working"
) -> ExportResult:
    need_images(case)
    k = export_camera(case, resolution)
    notes: list[str] = []
    png_scale = png_depth_scale(deepest_depth(case))
    entries, png_entries, written = [], [], 0
    for f, px in frame_pixels(case, resolution):
        name = f"{f.index:06d}.png"
        if resolution == "working":
            place(f.image, out / "images" / name, symlink)  # type: ignore[arg-type]
        else:
            write_png(out / "images" / name, cv2.cvtColor(px.rgb, cv2.COLOR_RGB2BGR))
        mask = None
        if f.mask is not None:
            if resolution == "working":
                place(f.mask, out / "masks" / name, symlink)
            else:
                write_png(out / "masks" / name, np.where(px.usable, 255, 0).astype(np.uint8))
            mask = f"masks/{name}"
        depth = png = None
        if px.depth is not None:
            (out / "depth").mkdir(exist_ok=True)
            np.save(out / "depth" / f"{f.index:06d}.npy", px.depth * NERFSTUDIO_DEPTH_FACTOR)
            d = np.where(np.isfinite(px.depth) & (px.depth > 0), px.depth, 0.0)
            write_png(
                out / "depth_png" / name,
                np.clip(np.round(d * png_scale), 0, 65535).astype(np.uint16),
            )
            depth, png = f"depth/{f.index:06d}.npy", f"depth_png/{name}"
            written += 1
        entries.append(TransformsEntry(f"images/{name}", mask, f.c2w, depth))
        png_entries.append(TransformsEntry(f"images/{name}", mask, f.c2w, png))
    about: dict = {
        "units": case.units,
        "metric": case.metric,
        "convention": "transform_matrix: OpenGL camera-to-world (x right, y up, z back)",
        "poses": case.poses_source,
        "resolution": resolution,
    }
    extra: dict = {"endopipe": about}
    if case.poses.points_path.is_file():
        shutil.copy2(case.poses.points_path, out / "sparse_pc.ply")
        extra["ply_file_path"] = "sparse_pc.ply"
    files = ["transforms.json"]
    if written:
        about["depth"] = (
            f"z-depth x {NERFSTUDIO_DEPTH_FACTOR:g} in {case.units}; nerfstudio's default "
            "depth_unit_scale_factor (1e-3) brings it back to the units of the poses"
        )
        factor = 1.0 / png_scale
        png_about = {
            **about,
            "depth": f"16-bit PNG, z-depth x {png_scale:g} in {case.units} (0 = unknown): "
            f"depth_unit_scale_factor {factor:g} brings it to the units of the poses",
            "depth_unit_scale_factor": factor,
        }
        png_extra = {**extra, "endopipe": png_about}
        write_transforms_json(out / PNG_TRANSFORMS, k, png_entries, extra=png_extra)
        files.append(PNG_TRANSFORMS)
        flag = f" with --depth-unit-scale-factor {factor:g}"
        flag = "" if png_scale == NERFSTUDIO_DEPTH_FACTOR else flag
        notes.append(
            f"depth also as 16-bit PNGs (depth_png/, z-depth x {png_scale:g}) for readers "
            f"without .npy: pass --data {PNG_TRANSFORMS}{flag}"
        )
        if written < len(case.frames):
            notes.append(f"depth for {written} of {len(case.frames)} frames")
        if resolution == "source":
            notes.append(UPSAMPLING)
    else:
        notes.append("no 05_depth: transforms.json without depth_file_path")
    write_transforms_json(out / "transforms.json", k, entries, extra=extra)
    if resolution == "source":
        notes.append(f"frames re-read from the input at {k.width}x{k.height}")
        if symlink:
            notes.append("--symlink: not at the source resolution (the frames are resampled)")
    if k.distorted:
        notes.append(f"lens: {k.model} {k.dist} in transforms.json (nerfstudio undistorts with it)")
    if case.refined:
        notes.append("poses refined by the NeRF: those the depth maps were rendered at")
    return ExportResult("nerfstudio", out, len(case.frames), files, notes)


def write_png(path: Path, img: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)
