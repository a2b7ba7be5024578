"""endonerf: EndoNeRF's layout, for EndoNeRF and the endoscopic Gaussian-splatting codebases.

`images/frame-<n>.color.png`, `depth/frame-<n>.depth.png` (16-bit, 0 = invalid),
`masks/frame-<n>.mask.png` (EndoNeRF's meaning, the inverse of endopipe's: 255 = exclude, e.g. a
tool or specular highlight), `poses_bounds.npy` (one row of 17 per frame: a 3x5 matrix flattened
row-major, `row[:15].reshape(3, 5)`, then near and far) and `endonerf.json` (the conventions).
The 3x5 is [c0 c1 c2 | t | hwf] with hwf = (height, width, focal) and the three rotation columns
the camera axes in world coordinates, in the order of `axes`:
  llff   LLFF's own (down, right, back) = (y, x, -z) of OpenCV, as written by LLFF's
         imgs2poses.py and read by loaders that apply LLFF's column swap (NeRF's load_llff,
         EndoNeRF with davinci_endoscopic=False);
  opengl (right, up, back) = (x, -y, -z): for loaders that take the matrix as a NeRF c2w
         unchanged (EndoNeRF's davinci_endoscopic=True path, Deform3DGS);
  opencv (right, down, forward) = (x, y, z): for loaders that take it as an OpenCV / COLMAP c2w
         (EndoGaussian).
The poses are those the depth was rendered at (refined by the NeRF when it refined them).

With a target (`--for`, targets.py) the files are what that loader takes: its axes; its image
size, one focal length and its principal point (the frames resampled and cropped: reframe.py);
depth PNGs and translations in one unit (translations x s, PNG = z-depth x s, s = 100 when the
deepest value fits), because the loaders back-project the raw PNG value with the translations as
they are; and pixels without depth excluded in masks/ (the loaders clip depth 0 up to their near
depth). Without a target (`--endonerf-axes` given) the layout is as before targets: the camera as
it is (an off-centre principal point or fx != fy only noted), depth x `depth_scale` with
translations in the case's units (the layout endopipe's own reader and SurgicalGaussian's
depth_scale read).

The format is pinhole-only: a lens that moves some pixel more than `MAX_LENS_SHIFT_PX` off the
pinhole's is refused, with the formats that carry it (nerfstudio, colmap), because the loaders
would cast every pixel's ray through the wrong point and the depth would land off the surface at
the edges; a smaller lens is left out and noted. near / far per frame are the 0.1 / 99.9
percentiles of the frame's depth (LLFF's rule), else of the sparse points in front of the camera,
else from the centre line's radius.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from pydantic import BaseModel, Field

from endopipe.export.case import CaseExport, ExportResult, need_images
from endopipe.export.pixels import UPSAMPLING, export_camera, frame_pixels
from endopipe.export.reframe import Reframe, reframe
from endopipe.export.targets import Target
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
    """What the pinhole-only format loses of the camera (written as it is, without a
    target); an EndopipeError for a lens."""
    notes = lens_notes(k)
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


def deepest_depth(case: CaseExport) -> float:
    """The largest depth of the exported frames' maps (0 without depth)."""
    deepest = 0.0
    for f in case.frames:
        if f.has_depth:
            d = case.depth(f)
            d = d[np.isfinite(d) & (d > 0)]
            deepest = max(deepest, float(d.max()) if d.size else 0.0)
    return deepest


def write_endonerf(
    case: CaseExport,
    out: Path,
    *,
    target: Target | None = None,
    axes: str | None = None,
    resolution: str = "working",
) -> ExportResult:
    """EndoNeRF's layout for `target`'s loader, or (`axes` given) as it was before targets: the
    camera as it is, depth x depth_scale, translations in the case's units."""
    if (target is None) == (axes is None):
        raise EndopipeError("give the EndoNeRF export a target (--for) or axes, not both")
    need_images(case)
    k = export_camera(case, resolution)
    has_depth = case.has_depth()
    scale = endonerf_depth_scale(deepest_depth(case))
    if target is None:
        notes = pinhole_notes(k)
        frame = Reframe(1.0, 1.0, 0.0, 0.0, k, 1.0)
        pose_scale, png_scale, meta_scale = 1.0, scale, scale
        axes_used = str(axes)
    else:
        notes = lens_notes(k)
        size = target.size or (k.width, k.height)
        frame = reframe(k, size, target.principal_point(*size))
        pose_scale = scale if has_depth else 1.0
        png_scale, meta_scale = pose_scale, 1.0
        axes_used = target.axes
        notes += target_notes(target, frame, case.units, pose_scale, has_depth)
    if resolution == "source":
        notes.append(f"frames re-read from the input at {k.width}x{k.height}")
        if has_depth:
            notes.append(UPSAMPLING)
    for sub in ("images", "masks", *(("depth",) if has_depth else ())):
        (out / sub).mkdir()
    bounds: list[tuple[float, float]] = []
    order = []  # the frames as written (the source is streamed in its own order)
    for n, (f, px) in enumerate(frame_pixels(case, resolution)):
        order.append(f)
        rgb, usable = frame.image(px.rgb), frame.mask(px.usable)
        cv2.imwrite(str(frame_file(out, "images", n)), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        depth = frame.depth(px.depth) if px.depth is not None else None
        excluded = ~usable
        if target is not None and depth is not None:
            excluded |= depth <= 0
        write_mask(out, n, excluded)
        if has_depth:
            d = depth if depth is not None else np.zeros(usable.shape, np.float32)
            write_depth_png(out, n, d, png_scale)
            bounds.append(_percentile_bounds(d[d > 0] * pose_scale, 1))
    filled = _filled(bounds) if has_depth else None
    if filled is not None:
        source = "depth maps"
    else:
        case_bounds, source = depth_bounds(case)
        filled = [(near * pose_scale, far * pose_scale) for near, far in case_bounds]
    notes.append(f"near/far bounds from {source}")
    c2ws = [_scaled_pose(f.c2w, pose_scale) for f in order]
    hwf = (float(frame.camera.height), float(frame.camera.width), float(frame.camera.fx))
    np.save(out / "poses_bounds.npy", poses_bounds(c2ws, hwf, filled, axes_used))
    if has_depth:
        notes.append(f"depth PNG = z-depth x {png_scale:g} ({case.units}); 0 = invalid")
        missing = sum(not f.has_depth for f in case.frames)
        if missing:
            notes.append(f"depth for {len(case.frames) - missing} of {len(case.frames)} frames")
    else:
        notes.append("no 05_depth: no depth/ folder (EndoNeRF's use_depth needs one)")
    meta = EndoNerfMeta(
        target=target.name if target is not None else None,
        loader=target.loader if target is not None else None,
        axes=axes_used,
        columns=AXES_DOC[axes_used],
        depth_scale=meta_scale if has_depth else None,
        pose_scale=pose_scale,
        units=case.units if pose_scale == 1.0 else f"{case.units} / {pose_scale:g}",
        width=frame.camera.width,
        height=frame.camera.height,
        focal=frame.camera.fx,
        cx=frame.camera.cx,
        cy=frame.camera.cy,
        resolution=resolution,
        bounds=source,
        camera=PINHOLE_ONLY,
        notes=notes,
    )
    write_json(out / "endonerf.json", meta.model_dump(mode="json"))
    files = ["poses_bounds.npy", "images", "masks", *(["depth"] if has_depth else [])]
    return ExportResult("endonerf", out, len(case.frames), files, notes)


def lens_notes(k: Camera) -> list[str]:
    """The pinhole-only format's note; an EndopipeError for a lens it cannot leave out."""
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
    return notes


def target_notes(
    target: Target, frame: Reframe, units: str, pose_scale: float, has_depth: bool
) -> list[str]:
    """What the export did for `target`'s loader, in a few lines."""
    k = frame.camera
    notes = [
        f"for {target.name} ({target.loader}): rotation columns {AXES_DOC[target.axes]}",
        f"images {k.width}x{k.height}, one focal length {k.fx:.3f} px, principal point "
        f"({k.cx:g}, {k.cy:g}) px (pixel centres)",
    ]
    if not frame.identity:
        notes.append(
            f"frames resampled x{frame.sx:.4f} across, x{frame.sy:.4f} down and cropped about "
            f"the principal point ({frame.kept:.0%} of the frame kept)"
        )
    if has_depth:
        notes.append(
            f"depth PNGs and translations in one unit, {units} / {pose_scale:g} (PNG value = "
            f"z-depth in it; translations x {pose_scale:g}): the loader's raw depth lands on "
            "the surface from every pose"
        )
        notes.append("pixels without depth are excluded in masks/ (the loaders clip depth 0 up)")
    return notes + list(target.notes)


class EndoNerfMeta(BaseModel):
    """endonerf.json: the conventions of the files beside it."""

    target: str | None = Field(description="the loader written for (--for); None: axes given")
    loader: str | None = Field(description="the public code the target follows")
    axes: str
    columns: str = Field(description="the rotation columns of poses_bounds.npy")
    depth_scale: float | None = Field(description="depth PNG counts per unit of the poses")
    pose_scale: float = Field(description="translations = the case's units x pose_scale")
    units: str = Field(description="the unit of the translations")
    width: int
    height: int
    focal: float
    cx: float = Field(description="principal point (px, pixel-centre convention)")
    cy: float
    resolution: str
    bounds: str = Field(description="where near / far came from")
    camera: str
    notes: list[str]


def _scaled_pose(c2w: np.ndarray, s: float) -> np.ndarray:
    out = np.array(c2w, dtype=np.float64)
    out[:3, 3] *= s
    return out
