"""endonerf: EndoNeRF's layout, for EndoNeRF and the endoscopic Gaussian-splatting codebases.

`images/frame-<n>.color.png`, `depth/frame-<n>.depth.png` (16-bit, depth x `depth_scale` in the
units of the poses, 0 = invalid; depth_scale = 100 when it fits: SurgicalGaussian's default),
`masks/frame-<n>.mask.png` (EndoNeRF's meaning, the inverse of endopipe's: 255 = exclude, e.g. a
tool or specular highlight) and `poses_bounds.npy`: one row of 17 per frame, a 3x5 matrix
flattened row-major (`row[:15].reshape(3, 5)`) then near and far bounds. The 3x5 is
[c0 c1 c2 | t | hwf] with hwf = (height, width, focal) and the three rotation columns the camera
axes in world coordinates, in the order of `axes`:
  llff   (default) LLFF's own (down, right, back) = (y, x, -z) of OpenCV, as written by LLFF's
         imgs2poses.py and read by loaders that apply LLFF's column swap (NeRF's load_llff,
         EndoNeRF with davinci_endoscopic=False);
  opengl (right, up, back) = (x, -y, -z): for loaders that take the matrix as a NeRF c2w
         unchanged (EndoNeRF's davinci_endoscopic=True path);
  opencv (right, down, forward) = (x, y, z): for loaders that take it as an OpenCV / COLMAP c2w.
The poses are those the depth was rendered at (refined by the NeRF when it refined them).

The format is pinhole-only: one focal length, a centred principal point, no lens. fx is written
(fx != fy or an off-centre principal point is noted); a lens that moves some pixel more than
`MAX_LENS_SHIFT_PX` off the pinhole's is refused, with the formats that carry it (nerfstudio,
colmap), because the loaders would cast every pixel's ray through the wrong point and the depth
would land off the surface at the edges; a smaller lens is left out and noted. near / far per
frame are the 0.1 / 99.9 percentiles of the frame's depth (LLFF's rule), else of the sparse
points in front of the camera, else from the centre line's radius.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np

from endopipe.export.case import CaseExport, ExportResult, need_images
from endopipe.pipeline.errors import EndopipeError
from endopipe.pipeline.stage import write_json
from endopipe.stages.camera import Camera, image_directions, lens_valid_mask

# The axes are the reader's (stages/io/endonerf.py): one definition for writing and reading.
from endopipe.stages.io.endonerf import ENDONERF_AXES as ENDONERF_AXES
from endopipe.stages.io.endonerf import LLFF_COLUMNS, c2w_from_llff

AXES_DOC = {
    "llff": "rotation columns = camera (down, right, back) in world coordinates (LLFF)",
    "opengl": "rotation columns = camera (right, up, back) in world coordinates (OpenGL)",
    "opencv": "rotation columns = camera (right, down, forward) in world coordinates",
}
#: The most a lens may move a pixel off the pinhole's for the pinhole-only format to take it.
MAX_LENS_SHIFT_PX = 0.5
PINHOLE_ONLY = "EndoNeRF's poses_bounds.npy is pinhole-only (one focal length, no lens)"


def llff_matrix(c2w: np.ndarray, hwf: tuple[float, float, float], axes: str = "llff") -> np.ndarray:
    """An OpenCV c2w as LLFF's 3x5 [c0 c1 c2 | t | hwf] with the rotation columns of `axes`."""
    m = np.zeros((3, 5))
    for col, (axis, sign) in enumerate(LLFF_COLUMNS[axes]):
        m[:, col] = sign * c2w[:3, axis]
    m[:, 3] = c2w[:3, 3]
    m[:, 4] = hwf
    return m


def poses_bounds(
    c2ws: list[np.ndarray] | np.ndarray,
    hwf: tuple[float, float, float],
    bounds: list[tuple[float, float]],
    axes: str = "llff",
) -> np.ndarray:
    """poses_bounds.npy's (N, 17) rows: each OpenCV c2w as LLFF's 3x5, flattened, then near
    and far."""
    rows = [
        np.concatenate([llff_matrix(c2w, hwf, axes).ravel(), [near, far]])
        for c2w, (near, far) in zip(c2ws, bounds, strict=True)
    ]
    return np.asarray(rows, dtype=np.float64)


def frame_file(out: Path, kind: str, n: int) -> Path:
    """EndoNeRF's name of the n-th frame's file of `kind` (images, masks or depth)."""
    suffix = {"images": "color", "masks": "mask", "depth": "depth"}[kind]
    return out / kind / f"frame-{n:06d}.{suffix}.png"


def write_mask(out: Path, n: int, excluded: np.ndarray) -> None:
    """The n-th frame's mask in EndoNeRF's meaning: 255 where `excluded` (a tool, a
    highlight), 0 where the pixel is used."""
    cv2.imwrite(str(frame_file(out, "masks", n)), np.where(excluded, 255, 0).astype(np.uint8))


def write_depth_png(out: Path, n: int, depth: np.ndarray, scale: float) -> None:
    """The n-th frame's 16-bit depth PNG: depth x `scale`, 0 = invalid (non-finite or <= 0)."""
    d = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0)
    png = np.clip(np.round(d * scale), 0, 65535).astype(np.uint16)
    cv2.imwrite(str(frame_file(out, "depth", n)), png)


def percentile_bounds(z: np.ndarray, enough: int = 1) -> tuple[float, float]:
    """LLFF's near / far from depths: their 0.1 and 99.9 percentiles (NaN: too few)."""
    return _percentile_bounds(z, enough)


def read_endonerf(folder: Path, axes: str = "llff") -> tuple[np.ndarray, list[np.ndarray]]:
    """poses_bounds.npy back to (N, 2) bounds and OpenCV c2w matrices."""
    arr = np.load(Path(folder) / "poses_bounds.npy")
    mats = arr[:, :15].reshape(-1, 3, 5)
    return arr[:, 15:], [c2w_from_llff(m, axes) for m in mats]


def lens_shift_px(camera: Camera) -> float:
    """How far (px) the lens moves a pixel off where a pinhole camera of the same intrinsics
    would see its ray: the error of reading the images as pinhole ones (0 for a pinhole)."""
    if not camera.distorted:
        return 0.0
    d = image_directions(camera)
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    shift = np.hypot(camera.fx * d[..., 0] + camera.cx - u, camera.fy * d[..., 1] + camera.cy - v)
    return float(shift[lens_valid_mask(camera)].max(initial=0.0))


def pinhole_notes(k: Camera) -> list[str]:
    """What the pinhole-only format loses of the camera; an EndopipeError for a lens."""
    shift = lens_shift_px(k)
    if shift > MAX_LENS_SHIFT_PX:
        raise EndopipeError(
            f"{PINHOLE_ONLY}, and this camera's {k.model} lens {k.dist} moves pixels up to "
            f"{shift:.1f} px off the pinhole's: its poses and depth would not meet; export "
            "nerfstudio or colmap, which carry the lens"
        )
    notes = [PINHOLE_ONLY]
    if k.distorted:
        notes.append(f"lens left out: it moves no pixel more than {shift:.2f} px")
    if abs(k.fx - k.fy) > 1e-3 * k.fx:
        notes.append(f"LLFF has one focal length: fx = {k.fx:.3f} written, fy = {k.fy:.3f} lost")
    cx0, cy0 = (k.width - 1) / 2, (k.height - 1) / 2
    if abs(k.cx - cx0) > 1.0 or abs(k.cy - cy0) > 1.0:
        notes.append(
            f"LLFF assumes a centred principal point; this camera's is ({k.cx:.1f}, {k.cy:.1f}) "
            f"px, the image centre ({cx0:.1f}, {cy0:.1f}) px"
        )
    return notes


def _percentile_bounds(z: np.ndarray, enough: int) -> tuple[float, float]:
    if len(z) < enough:
        return (np.nan, np.nan)
    return (float(np.percentile(z, 0.1)), float(np.percentile(z, 99.9)))


def _filled(bounds: list[tuple[float, float]]) -> list[tuple[float, float]] | None:
    """Frames without bounds get the widest of the others'; None when none has any."""
    good = [b for b in bounds if np.isfinite(b[0])]
    if not good:
        return None
    fill = (min(b[0] for b in good), max(b[1] for b in good))
    return [b if np.isfinite(b[0]) else fill for b in bounds]


def depth_bounds(case: CaseExport) -> tuple[list[tuple[float, float]], str]:
    """(near, far) per frame and where they came from."""
    if case.has_depth() and all(f.has_depth for f in case.frames):
        out = []
        for f in case.frames:
            d = case.depth(f)
            out.append(_percentile_bounds(d[(d > 0) & np.isfinite(d)], 1))
        if (filled := _filled(out)) is not None:
            return filled, "depth maps"
    pts = case.poses.points()
    if len(pts) >= 20:
        out = []
        for f in case.frames:
            w2c = np.linalg.inv(f.c2w)
            z = (pts @ w2c[:3, :3].T + w2c[:3, 3])[:, 2]
            out.append(_percentile_bounds(z[z > 0], 10))
        if (filled := _filled(out)) is not None:
            return filled, "sparse points"
    radius = _centerline_radius(case)
    if radius is not None:
        return [(0.05 * radius, 6.0 * radius)] * len(case.frames), "centre line radius"
    centres = np.array([f.c2w[:3, 3] for f in case.frames])
    extent = float(np.ptp(centres, axis=0).max()) if len(centres) > 1 else 1.0
    extent = extent or 1.0
    return [(0.01 * extent, 2.0 * extent)] * len(case.frames), "camera path extent (guess)"


def _centerline_radius(case: CaseExport) -> float | None:
    from endopipe.stages.centerline.view import CenterlineView

    view = case.view("centerline", CenterlineView)
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
    need_images(case)
    k = case.intrinsics
    notes = pinhole_notes(k)
    bounds, source = depth_bounds(case)
    notes.append(f"near/far bounds from {source}")
    hwf = (float(k.height), float(k.width), float(k.fx))
    np.save(out / "poses_bounds.npy", poses_bounds([f.c2w for f in case.frames], hwf, bounds, axes))
    write_images_and_masks(case, out)
    files = ["poses_bounds.npy", "images", "masks"]
    scale = None
    if case.has_depth():
        scale, depth_notes = write_depth_pngs(case, out)
        files.append("depth")
        notes += depth_notes
    else:
        notes.append("no 05_depth: no depth/ folder (EndoNeRF's use_depth needs one)")
    meta = {"axes": axes, "columns": AXES_DOC[axes], "depth_scale": scale, "bounds": source}
    write_json(out / "endonerf.json", {**meta, "camera": PINHOLE_ONLY})
    return ExportResult("endonerf", out, len(case.frames), files, notes)


def write_images_and_masks(case: CaseExport, out: Path) -> None:
    """Frames as `frame-<n>.color.png`, masks inverted to EndoNeRF's meaning (255 = exclude)."""
    k = case.intrinsics
    (out / "images").mkdir()
    (out / "masks").mkdir()
    for n, f in enumerate(case.frames):
        shutil.copy2(f.image, frame_file(out, "images", n))  # type: ignore[arg-type]
        usable = cv2.imread(str(f.mask), cv2.IMREAD_GRAYSCALE) if f.mask is not None else None
        if usable is None:
            usable = np.full((k.height, k.width), 255, np.uint8)
        write_mask(out, n, usable <= 127)


def write_depth_pngs(case: CaseExport, out: Path) -> tuple[float, list[str]]:
    """16-bit depth PNGs (0 = invalid) for every frame; the scale and notes."""
    k = case.intrinsics
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
        write_depth_png(out, n, d, scale)
    notes = [f"depth PNG = z-depth x {scale:g} ({case.units}); 0 = invalid"]
    if len(depths) < len(case.frames):
        notes.append(f"depth for {len(depths)} of {len(case.frames)} frames (rest: 0)")
    return scale, notes
