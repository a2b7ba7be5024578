"""`endopipe export`: a processed case in other tools' formats. Plain functions over folders.

Every format writes `export.json` (what was exported, units, conventions, skipped frames) next
to its files. Only registered frames are exported (in endopipe's frame order); the images are the
working-resolution frames of 01_ingest, and intrinsics are scaled to them.

nerfstudio  `transforms.json` (OpenGL camera axes: x right, y up, z back, i.e. endopipe's
            OpenCV c2w with its y and z axes negated; principal point in nerfstudio's
            pixel-edge convention, OpenCV + 0.5), `images/`, `masks/` (255 = use, nerfstudio's
            meaning too) and, with 05_depth, `depth/<index>.npy` + `depth_file_path` per frame.
            Depth files hold z-depth x 1000 in the units of the poses: nerfstudio multiplies
            depth by `depth_unit_scale_factor` (default 1e-3, "millimetres to metres") to bring
            it into the units of the poses, so the default is right. With 02_poses/points.ply
            also `sparse_pc.ply` + `ply_file_path` (splatfacto's initial points).
colmap      `sparse/0/{cameras,images,points3D}.txt` + `images/`: 02_poses/sparse copied when
            present (COLMAP's own model, with its tracks), else written from cameras.json
            (camera model as estimated, PINHOLE when no parameters; images.txt holds
            world-to-camera qvec (w, x, y, z) and tvec; empty points3D.txt).
endonerf    EndoNeRF's layout: `images/frame-<n>.color.png`, `depth/frame-<n>.depth.png`
            (16-bit, depth x `depth_scale` in the units of the poses, 0 = invalid;
            depth_scale = 100 when it fits: SurgicalGaussian's default), `masks/frame-<n>.mask.png`
            (EndoNeRF's meaning, the inverse of endopipe's: 255 = exclude, e.g. a tool or
            specular highlight) and `poses_bounds.npy`: one row of 17 per frame, a 3x5 matrix
            flattened row-major (`row[:15].reshape(3, 5)`) then near and far bounds. The 3x5 is
            [c0 c1 c2 | t | hwf] with hwf = (height, width, focal) and the three rotation columns
            the camera axes in world coordinates, in the order of `axes`:
              llff   (default) LLFF's own (down, right, back) = (y, x, -z) of OpenCV, as written
                     by LLFF's imgs2poses.py and read by loaders that apply LLFF's column swap
                     (NeRF's load_llff, EndoNeRF with davinci_endoscopic=False);
              opengl (right, up, back) = (x, -y, -z): for loaders that take the matrix as a
                     NeRF c2w unchanged (EndoNeRF's davinci_endoscopic=True path);
              opencv (right, down, forward) = (x, y, z): for loaders that take it as an OpenCV
                     / COLMAP c2w (3D-Gaussian-splatting-based endoscopic codebases).
            LLFF has one focal length and a centred principal point: fx is written (fx != fy or
            an off-centre principal point is noted in export.json). near / far per frame are the
            0.1 / 99.9 percentiles of the frame's depth (LLFF's rule), else of the sparse points
            in front of the camera, else from the centre line's radius.
ply         `mesh.ply` (06_mesh, world frame), `points.ply`: a coloured point cloud fused from
            05_depth (every `point_stride`-th pixel inside the usable mask, back-projected with
            the frame's pose; voxel-thinned to at most `max_points`), and `cameras.ply`: the
            camera centres, in frame order.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import cv2
import numpy as np

from endopipe.pipeline.errors import EndopipeError
from endopipe.pipeline.stage import write_json
from endopipe.stages.camera import Camera, backproject
from endopipe.stages.depth.view import DepthView
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.colmap_model import (
    OPENGL_FROM_OPENCV,
    write_ply,
    write_text_model,
    write_transforms_json,
)
from endopipe.stages.poses.view import PosesView

FORMATS = ("nerfstudio", "colmap", "endonerf", "ply")
ENDONERF_AXES = ("llff", "opengl", "opencv")

#: For each `axes` choice: which OpenCV camera axis (0 = x, 1 = y, 2 = z) and sign fill the
#: three rotation columns of an LLFF 3x5 matrix.
LLFF_COLUMNS: dict[str, tuple[tuple[int, float], ...]] = {
    "llff": ((1, 1.0), (0, 1.0), (2, -1.0)),  # down, right, back
    "opengl": ((0, 1.0), (1, -1.0), (2, -1.0)),  # right, up, back
    "opencv": ((0, 1.0), (1, 1.0), (2, 1.0)),  # right, down, forward
}
#: nerfstudio divides depth files by 1000 by default (depth_unit_scale_factor = 1e-3).
NERFSTUDIO_DEPTH_FACTOR = 1000.0

V = TypeVar("V")


@dataclass
class ExportResult:
    format: str
    out: Path
    frames: int
    files: list[str]
    notes: list[str] = field(default_factory=list)


@dataclass
class ExportFrame:
    index: int
    source_index: int
    image: Path | None
    mask: Path | None
    has_depth: bool
    c2w: np.ndarray


@dataclass
class CaseExport:
    """What every format needs: the camera at image resolution and the registered frames, and
    the views of the stages that wrote them."""

    case_dir: Path
    folders: dict[str, Path]
    poses: PosesView
    intrinsics: Camera  # at the exported images' resolution, with its lens distortion
    frames: list[ExportFrame]
    skipped: list[int]
    depth_view: DepthView | None = None

    @property
    def metric(self) -> bool:
        return self.poses.metric

    @property
    def units(self) -> str:
        return "mm" if self.poses.metric else self.poses.file.units

    def has_depth(self) -> bool:
        return any(f.has_depth for f in self.frames)

    def depth(self, frame: ExportFrame) -> np.ndarray:
        """The frame's z-depth map from 05_depth (only for frames with `has_depth`)."""
        assert self.depth_view is not None and frame.has_depth
        return self.depth_view.depth(frame.index)


# --- reading a case through its stages' views -----------------------------------------------------


def _view(folders: Mapping[str, Path], stage: str, reader: Callable[[Path], V]) -> V | None:
    """The view of a stage's published folder, or None when the case has not run it."""
    folder = folders.get(stage)
    if folder is None or not Path(folder).is_dir():
        return None
    try:
        return reader(Path(folder))
    except FileNotFoundError:
        return None


def load_case_export(case_dir: Path, folders: Mapping[str, Path]) -> CaseExport:
    """The case's registered frames, read through the stage views; `folders` maps a stage name
    to its published folder (the engine's `Pipeline.folders`)."""
    case_dir = Path(case_dir)
    folders = {name: Path(f) for name, f in folders.items()}
    poses = _view(folders, "poses", PosesView)
    if poses is None:
        raise EndopipeError(
            f"{case_dir.name} has no camera poses (02_poses/cameras.json); run "
            "`endopipe run INPUT --until poses` first"
        )
    ingest = _view(folders, "ingest", IngestView)
    depth = _view(folders, "depth", DepthView)
    cams = poses.file
    size = (ingest.width, ingest.height) if ingest is not None else (cams.width, cams.height)
    k = poses.intrinsics
    if (k.width, k.height) != size:
        k = k.scaled(*size)
    with_depth = set(depth.indices) if depth is not None else set()
    frames, skipped = [], []
    for fp in cams.frames:
        if not fp.registered or fp.c2w is None:
            skipped.append(fp.index)
            continue
        kept = ingest is not None and ingest.has_frame(fp.index)
        image = ingest.image_path(fp.index) if kept else None
        mask = ingest.mask_path(fp.index) if kept else None
        frames.append(
            ExportFrame(
                index=fp.index,
                source_index=ingest.frame(fp.index).source_index if kept else fp.index,
                image=image if image is not None and image.is_file() else None,
                mask=mask if mask is not None and mask.is_file() else None,
                has_depth=fp.index in with_depth,
                c2w=np.asarray(fp.c2w, dtype=np.float64),
            )
        )
    if not frames:
        raise EndopipeError(f"{case_dir.name}: no registered frame in 02_poses/cameras.json")
    return CaseExport(case_dir, folders, poses, k, frames, skipped, depth)


# --- the entry point ----------------------------------------------------------------------------


def export_case(
    case_dir: Path,
    fmt: str,
    out: Path | None = None,
    *,
    folders: Mapping[str, Path],
    symlink: bool = False,
    endonerf_axes: str = "llff",
    point_stride: int = 4,
    max_points: int = 2_000_000,
) -> ExportResult:
    """Write `case_dir` in format `fmt` to `out` (default `<case>/exports/<fmt>`). `folders`:
    each stage's published folder by stage name (`Pipeline.folders`: the engine names them).

    The folder is written beside `out` and renamed into place; an existing `out` is replaced
    only when it is an earlier endopipe export (it holds export.json), never a foreign folder.
    """
    if fmt not in FORMATS:
        raise EndopipeError(f"unknown export format '{fmt}'; formats: {', '.join(FORMATS)}")
    if endonerf_axes not in ENDONERF_AXES:
        raise EndopipeError(
            f"unknown EndoNeRF axes '{endonerf_axes}'; choose one of {', '.join(ENDONERF_AXES)}"
        )
    case = load_case_export(case_dir, folders)
    out = Path(out) if out is not None else Path(case_dir) / "exports" / fmt
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not _ours(out))):
        raise EndopipeError(
            f"{out} exists and is not an endopipe export; give an empty or new folder with --out"
        )
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.parent / f".{out.name}.tmp-export"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    writers: dict[str, Callable[..., ExportResult]] = {
        "nerfstudio": lambda: write_nerfstudio(case, tmp, symlink=symlink),
        "colmap": lambda: write_colmap(case, tmp, symlink=symlink),
        "endonerf": lambda: write_endonerf(case, tmp, axes=endonerf_axes),
        "ply": lambda: write_ply_export(case, tmp, stride=point_stride, max_points=max_points),
    }
    try:
        result = writers[fmt]()
        if case.skipped:
            result.notes.append(f"{len(case.skipped)} unregistered frame(s) left out")
        write_json(
            tmp / "export.json",
            {
                "format": fmt,
                "case": str(Path(case_dir).resolve()),
                "frames": [f.index for f in case.frames],
                "source_indices": [f.source_index for f in case.frames],
                "skipped_unregistered": case.skipped,
                "units": case.units,
                "metric": case.metric,
                "intrinsics": case.intrinsics.model_dump(exclude_none=True),
                "notes": result.notes,
                "files": result.files,
                **({"endonerf_axes": endonerf_axes} if fmt == "endonerf" else {}),
            },
        )
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    result.out = out
    return result


def _ours(folder: Path) -> bool:
    return (folder / "export.json").is_file()


def _place(src: Path, dst: Path, symlink: bool) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    if symlink:
        dst.symlink_to(src.resolve())
    else:
        shutil.copy2(src, dst)


def _need_images(case: CaseExport) -> None:
    missing = [f.index for f in case.frames if f.image is None]
    if missing:
        raise EndopipeError(
            f"{case.case_dir.name}: frame image(s) missing for {len(missing)} registered frame(s) "
            "(01_ingest/frames/); re-run `endopipe run INPUT --until ingest`"
        )


# --- nerfstudio -----------------------------------------------------------------------------------


def write_nerfstudio(case: CaseExport, out: Path, *, symlink: bool = False) -> ExportResult:
    _need_images(case)
    notes, frames = [], []
    for f in case.frames:
        name = f"{f.index:06d}.png"
        _place(f.image, out / "images" / name, symlink)  # type: ignore[arg-type]
        mask = None
        if f.mask is not None:
            _place(f.mask, out / "masks" / name, symlink)
            mask = f"masks/{name}"
        frames.append((f"images/{name}", mask, f.c2w))
    extra: dict = {
        "endopipe": {
            "units": case.units,
            "metric": case.metric,
            "convention": "transform_matrix: OpenGL camera-to-world (x right, y up, z back)",
        }
    }
    if case.poses.points_path.is_file():
        shutil.copy2(case.poses.points_path, out / "sparse_pc.ply")
        extra["ply_file_path"] = "sparse_pc.ply"
    write_transforms_json(out / "transforms.json", case.intrinsics, frames, extra=extra)
    if case.has_depth():
        data = json.loads((out / "transforms.json").read_text())
        (out / "depth").mkdir()
        written = 0
        for f, entry in zip(case.frames, data["frames"], strict=True):
            if not f.has_depth:
                continue
            d = case.depth(f).astype(np.float32) * NERFSTUDIO_DEPTH_FACTOR
            np.save(out / "depth" / f"{f.index:06d}.npy", d)
            entry["depth_file_path"] = f"depth/{f.index:06d}.npy"
            written += 1
        data["endopipe"]["depth"] = (
            f"z-depth x {NERFSTUDIO_DEPTH_FACTOR:g} in {case.units}; nerfstudio's default "
            "depth_unit_scale_factor (1e-3) brings it back to the units of the poses"
        )
        (out / "transforms.json").write_text(json.dumps(data, indent=2) + "\n")
        if written < len(case.frames):
            notes.append(f"depth for {written} of {len(case.frames)} frames")
    else:
        notes.append("no 05_depth: transforms.json without depth_file_path")
    return ExportResult("nerfstudio", out, len(case.frames), ["transforms.json"], notes)


def read_nerfstudio(folder: Path) -> tuple[Camera, dict[str, np.ndarray]]:
    """transforms.json back to OpenCV intrinsics and c2w by image file name (for tests)."""
    data = json.loads((Path(folder) / "transforms.json").read_text())
    k = Camera(
        width=data["w"],
        height=data["h"],
        fx=data["fl_x"],
        fy=data["fl_y"],
        cx=data["cx"] - 0.5,
        cy=data["cy"] - 0.5,
    )
    poses = {
        Path(f["file_path"]).name: np.asarray(f["transform_matrix"]) @ OPENGL_FROM_OPENCV
        for f in data["frames"]
    }
    return k, poses


# --- colmap ---------------------------------------------------------------------------------------


def write_colmap(case: CaseExport, out: Path, *, symlink: bool = False) -> ExportResult:
    _need_images(case)
    notes = []
    for f in case.frames:
        _place(f.image, out / "images" / f.image.name, symlink)  # type: ignore[union-attr]
    sparse = out / "sparse" / "0"
    src = case.poses.sparse_dir
    model_files = [
        src / f"{name}.{ext}"
        for name in ("cameras", "images", "points3D")
        for ext in ("txt", "bin")
        if (src / f"{name}.{ext}").is_file()
    ]
    if _colmap_model_complete(src):
        sparse.mkdir(parents=True)
        for p in model_files:
            shutil.copy2(p, sparse / p.name)
        notes.append("02_poses/sparse copied as it is (with its tracks, if any)")
    else:
        write_text_model(
            sparse,
            case.intrinsics,
            {f.image.name: f.c2w for f in case.frames},  # type: ignore[union-attr]
        )
        notes.append("sparse model written from cameras.json (no tracks: empty points3D.txt)")
    return ExportResult("colmap", out, len(case.frames), ["sparse/0", "images"], notes)


def _colmap_model_complete(folder: Path) -> bool:
    return all(
        any((folder / f"{name}.{ext}").is_file() for ext in ("txt", "bin"))
        for name in ("cameras", "images", "points3D")
    )


def llff_matrix(c2w: np.ndarray, hwf: tuple[float, float, float], axes: str = "llff") -> np.ndarray:
    """An OpenCV c2w as LLFF's 3x5 [c0 c1 c2 | t | hwf] with the rotation columns of `axes`."""
    m = np.zeros((3, 5))
    for col, (axis, sign) in enumerate(LLFF_COLUMNS[axes]):
        m[:, col] = sign * c2w[:3, axis]
    m[:, 3] = c2w[:3, 3]
    m[:, 4] = hwf
    return m


def c2w_from_llff(m: np.ndarray, axes: str = "llff") -> np.ndarray:
    """LLFF's 3x5 (rotation columns in the order of `axes`) back to an OpenCV c2w."""
    c2w = np.eye(4)
    for col, (axis, sign) in enumerate(LLFF_COLUMNS[axes]):
        c2w[:3, axis] = sign * m[:, col]
    c2w[:3, 3] = m[:, 3]
    return c2w


def depth_bounds(case: CaseExport) -> tuple[list[tuple[float, float]], str]:
    """(near, far) per frame and where they came from."""
    if case.has_depth() and all(f.has_depth for f in case.frames):
        out = []
        for f in case.frames:
            d = case.depth(f)
            z = d[(d > 0) & np.isfinite(d)]
            out.append(
                (float(np.percentile(z, 0.1)), float(np.percentile(z, 99.9)))
                if z.size
                else (np.nan, np.nan)
            )
        good = [b for b in out if np.isfinite(b[0])]
        if good:
            fill = (min(b[0] for b in good), max(b[1] for b in good))
            return [b if np.isfinite(b[0]) else fill for b in out], "depth maps"
    pts = case.poses.points()
    if len(pts) >= 20:
        out = []
        for f in case.frames:
            w2c = np.linalg.inv(f.c2w)
            z = (pts @ w2c[:3, :3].T + w2c[:3, 3])[:, 2]
            z = z[z > 0]
            out.append(
                (float(np.percentile(z, 0.1)), float(np.percentile(z, 99.9)))
                if len(z) >= 10
                else (np.nan, np.nan)
            )
        good = [b for b in out if np.isfinite(b[0])]
        if good:
            fill = (min(b[0] for b in good), max(b[1] for b in good))
            return [b if np.isfinite(b[0]) else fill for b in out], "sparse points"
    radius = _centerline_radius(case)
    if radius is not None:
        return [(0.05 * radius, 6.0 * radius)] * len(case.frames), "centre line radius"
    centres = np.array([f.c2w[:3, 3] for f in case.frames])
    extent = float(np.ptp(centres, axis=0).max()) if len(centres) > 1 else 1.0
    extent = extent or 1.0
    return [(0.01 * extent, 2.0 * extent)] * len(case.frames), "camera path extent (guess)"


def _centerline_radius(case: CaseExport) -> float | None:
    from endopipe.stages.centerline.view import CenterlineView

    view = _view(case.folders, "centerline", CenterlineView)
    radius = view.radius if view is not None else []
    return float(np.median(radius)) if len(radius) else None


def endonerf_depth_scale(max_depth: float) -> float:
    """Counts per unit of the 16-bit depth PNGs: 100 (0.01 mm steps) when the deepest value
    fits, else the largest power of ten that keeps it under 65535."""
    if max_depth <= 0 or not np.isfinite(max_depth):
        return 100.0
    scale = 100.0
    while max_depth * scale > 65535 and scale > 1e-12:
        scale /= 10.0
    return scale


def write_endonerf(case: CaseExport, out: Path, *, axes: str = "llff") -> ExportResult:
    _need_images(case)
    k = case.intrinsics
    notes = []
    if abs(k.fx - k.fy) > 1e-3 * k.fx:
        notes.append(f"LLFF has one focal length: fx = {k.fx:.3f} written, fy = {k.fy:.3f} lost")
    cx0, cy0 = (k.width - 1) / 2, (k.height - 1) / 2
    if abs(k.cx - cx0) > 1.0 or abs(k.cy - cy0) > 1.0:
        notes.append(
            f"LLFF assumes a centred principal point; this camera's is ({k.cx:.1f}, {k.cy:.1f}) "
            f"px, the image centre ({cx0:.1f}, {cy0:.1f}) px"
        )
    if case.intrinsics.distorted:
        notes.append(f"lens distortion of the {case.intrinsics.model} lens is not representable")
    bounds, source = depth_bounds(case)
    notes.append(f"near/far bounds from {source}")
    hwf = (float(k.height), float(k.width), float(k.fx))
    rows = []
    for f, (near, far) in zip(case.frames, bounds, strict=True):
        rows.append(np.concatenate([llff_matrix(f.c2w, hwf, axes).ravel(), [near, far]]))
    np.save(out / "poses_bounds.npy", np.asarray(rows, dtype=np.float64))
    (out / "images").mkdir()
    (out / "masks").mkdir()
    for n, f in enumerate(case.frames):
        stem = f"frame-{n:06d}"
        shutil.copy2(f.image, out / "images" / f"{stem}.color.png")  # type: ignore[arg-type]
        usable = cv2.imread(str(f.mask), cv2.IMREAD_GRAYSCALE) if f.mask is not None else None
        if usable is None:
            usable = np.full((k.height, k.width), 255, np.uint8)
        excluded = np.where(usable > 127, 0, 255).astype(np.uint8)
        cv2.imwrite(str(out / "masks" / f"{stem}.mask.png"), excluded)
    files = ["poses_bounds.npy", "images", "masks"]
    scale = None
    if case.has_depth():
        depths = {f.index: case.depth(f) for f in case.frames if f.has_depth}
        deepest = max((float(np.nanmax(d)) for d in depths.values() if d.size), default=0.0)
        scale = endonerf_depth_scale(deepest)
        (out / "depth").mkdir()
        for n, f in enumerate(case.frames):
            d = depths.get(f.index)
            if d is None:
                d = np.zeros((k.height, k.width), np.float32)
            if d.shape != (k.height, k.width):
                d = cv2.resize(d, (k.width, k.height), interpolation=cv2.INTER_NEAREST)
            d = np.where(np.isfinite(d) & (d > 0), d, 0.0)
            png = np.clip(np.round(d * scale), 0, 65535).astype(np.uint16)
            cv2.imwrite(str(out / "depth" / f"frame-{n:06d}.depth.png"), png)
        files.append("depth")
        notes.append(f"depth PNG = z-depth x {scale:g} ({case.units}); 0 = invalid")
        if len(depths) < len(case.frames):
            notes.append(f"depth for {len(depths)} of {len(case.frames)} frames (rest: 0)")
    else:
        notes.append("no 05_depth: no depth/ folder (EndoNeRF's use_depth needs one)")
    result = ExportResult("endonerf", out, len(case.frames), files, notes)
    meta = {"axes": axes, "columns": _axes_doc(axes), "depth_scale": scale, "bounds": source}
    write_json(out / "endonerf.json", meta)
    return result


def _axes_doc(axes: str) -> str:
    return {
        "llff": "rotation columns = camera (down, right, back) in world coordinates (LLFF)",
        "opengl": "rotation columns = camera (right, up, back) in world coordinates (OpenGL)",
        "opencv": "rotation columns = camera (right, down, forward) in world coordinates",
    }[axes]


def read_endonerf(folder: Path, axes: str = "llff") -> tuple[np.ndarray, list[np.ndarray]]:
    """poses_bounds.npy back to (N, 2) bounds and OpenCV c2w matrices (for tests)."""
    arr = np.load(Path(folder) / "poses_bounds.npy")
    mats = arr[:, :15].reshape(-1, 3, 5)
    return arr[:, 15:], [c2w_from_llff(m, axes) for m in mats]


# --- ply ------------------------------------------------------------------------------------------


def fuse_depth(
    case: CaseExport, stride: int = 4, max_points: int = 2_000_000
) -> tuple[np.ndarray, np.ndarray]:
    """World points (N, 3) and colours (N, 3 uint8) back-projected from the depth maps."""
    xyz, rgb = [], []
    for f in case.frames:
        if not f.has_depth:
            continue
        d = case.depth(f).astype(np.float64)
        h, w = d.shape
        k = (
            case.intrinsics
            if (case.intrinsics.width, case.intrinsics.height) == (w, h)
            else (case.intrinsics.scaled(w, h))
        )
        valid = (d > 0) & np.isfinite(d)
        if f.mask is not None:
            m = cv2.imread(str(f.mask), cv2.IMREAD_GRAYSCALE)
            if m is not None:
                valid &= cv2.resize(m, (w, h), interpolation=cv2.INTER_NEAREST) > 127
        sub = np.zeros_like(valid)
        sub[::stride, ::stride] = True
        valid &= sub
        pts = backproject(k, d, f.c2w)[valid]
        if f.image is not None:
            img = cv2.imread(str(f.image), cv2.IMREAD_COLOR)
            img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
            col = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)[valid]
        else:
            col = np.full((len(pts), 3), 200, np.uint8)
        xyz.append(pts)
        rgb.append(col)
    if not xyz:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    points, colours = np.concatenate(xyz), np.concatenate(rgb)
    if len(points) > max_points:
        points, colours = voxel_thin(points, colours, max_points)
    return points, colours


def voxel_thin(
    points: np.ndarray, colours: np.ndarray, max_points: int
) -> tuple[np.ndarray, np.ndarray]:
    """open3d's voxel down-sampling (one point per voxel: the mean of its points and colours),
    the voxel grown until at most `max_points` remain."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    cloud.colors = o3d.utility.Vector3dVector(np.asarray(colours, np.float64) / 255.0)
    extent = float(np.ptp(points, axis=0).max()) or 1.0
    size = extent / max(np.cbrt(max_points), 1.0) / 4
    for _ in range(40):
        thin = cloud.voxel_down_sample(size)
        if len(thin.points) <= max_points:
            rgb = np.round(np.asarray(thin.colors) * 255.0).clip(0, 255).astype(np.uint8)
            return np.asarray(thin.points), rgb
        size *= 1.25
    return points[:max_points], colours[:max_points]


def write_ply_export(
    case: CaseExport, out: Path, *, stride: int = 4, max_points: int = 2_000_000
) -> ExportResult:
    notes, files = [], []
    from endopipe.stages.mesh.view import MeshView

    mesh = _view(case.folders, "mesh", MeshView)
    if mesh is not None and mesh.mesh_path.is_file():
        shutil.copy2(mesh.mesh_path, out / "mesh.ply")
        files.append("mesh.ply")
    else:
        notes.append("no 06_mesh/mesh.ply")
    if case.has_depth():
        xyz, rgb = fuse_depth(case, stride, max_points)
        write_ply(out / "points.ply", xyz, rgb)
        files.append("points.ply")
        notes.append(f"points.ply: {len(xyz):,} points fused from the depth maps (stride {stride})")
    else:
        notes.append("no 05_depth: no fused point cloud")
    if not files:
        raise EndopipeError(
            f"{case.case_dir.name}: nothing to export as PLY (no 06_mesh/mesh.ply, no 05_depth); "
            "run the pipeline through the depth or mesh stage first"
        )
    centres = np.array([f.c2w[:3, 3] for f in case.frames])
    write_ply(out / "cameras.ply", centres, np.tile([255, 64, 32], (len(centres), 1)))
    files.append("cameras.ply")
    return ExportResult("ply", out, len(case.frames), files, notes)
