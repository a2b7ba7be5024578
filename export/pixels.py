"""The exported frames' pixels at the chosen resolution (`--resolution working|source`).

working: 01_ingest's frames and masks and 05_depth's maps, as the pipeline made them.
source: the input's frames re-read at their full size, through the reader ingest used (the
ingest view says which input and reader); the camera scaled to them; masks upsampled (nearest);
depth upsampled edge-aware by a joint bilateral filter guided by the full-size frame (kornia's
`joint_bilateral_blur`), normalised over the valid samples so 0 = unknown is never averaged in
and stays unknown where its nearest working pixel was.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from endopipe.export.case import CaseExport, ExportFrame
from endopipe.pipeline.errors import EndopipeError
from endopipe.stages.camera import Camera

RESOLUTIONS = ("working", "source")
#: The joint bilateral filter's colour sigma (grey levels 0..1).
SIGMA_COLOR = 0.1
UPSAMPLING = (
    "depth upsampled to the source size edge-aware: nearest samples filtered by a joint "
    f"bilateral filter guided by the full-size frame (kornia, colour sigma {SIGMA_COLOR}, "
    "spatial sigma = the scale factor), over valid samples only"
)


@dataclass
class Pixels:
    """One frame at the export's resolution."""

    rgb: np.ndarray  # H x W x 3 uint8, RGB
    usable: np.ndarray  # bool H x W: endopipe's mask (inside the field of view, no highlight/tool)
    depth: np.ndarray | None  # float32 z-depth in the case's units, 0 = unknown; None: no depth


def export_camera(case: CaseExport, resolution: str) -> Camera:
    """The camera at the exported frames' size (the working frames', or the source's)."""
    if resolution not in RESOLUTIONS:
        raise EndopipeError(f"unknown resolution '{resolution}'; choose {' or '.join(RESOLUTIONS)}")
    if resolution == "working":
        return case.intrinsics
    w, h = source_size(case)
    return case.intrinsics.scaled(w, h)


def frame_pixels(case: CaseExport, resolution: str) -> Iterator[tuple[ExportFrame, Pixels]]:
    """Every exported frame's pixels, in frame order (the source is streamed once)."""
    if resolution == "working":
        for f in case.frames:
            yield f, working_pixels(case, f)
        return
    k = export_camera(case, "source")
    wanted = {f.source_index: f for f in case.frames}
    for frame in _open_source(case).frames():
        f = wanted.pop(frame.source_index, None)
        if f is None:
            continue
        yield f, upsampled(case, f, frame.rgb, k)
        if not wanted:
            return
    if wanted:
        raise EndopipeError(
            f"the input no longer holds {len(wanted)} exported frame(s) (source frames "
            f"{sorted(wanted)[:5]}...); export at --resolution working"
        )


def working_pixels(case: CaseExport, f: ExportFrame) -> Pixels:
    rgb = cv2.cvtColor(cv2.imread(str(f.image)), cv2.COLOR_BGR2RGB)
    h, w = rgb.shape[:2]
    mask = cv2.imread(str(f.mask), cv2.IMREAD_GRAYSCALE) if f.mask is not None else None
    usable = mask > 127 if mask is not None else np.ones((h, w), bool)
    depth = None
    if f.has_depth:
        depth = case.depth(f).astype(np.float32)
        if depth.shape != (h, w):
            depth = cv2.resize(depth, (w, h), interpolation=cv2.INTER_NEAREST)
    return Pixels(rgb, usable, depth)


def upsampled(case: CaseExport, f: ExportFrame, rgb: np.ndarray, k: Camera) -> Pixels:
    """The working frame's mask and depth brought to the full-size frame `rgb`."""
    if rgb.shape[:2] != (k.height, k.width):
        raise EndopipeError(
            f"source frame {f.source_index} is {rgb.shape[1]}x{rgb.shape[0]}, the first was "
            f"{k.width}x{k.height}; export at --resolution working"
        )
    low = working_pixels(case, f)
    size = (k.width, k.height)
    usable = cv2.resize(low.usable.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    depth = None if low.depth is None else joint_bilateral_upsample(low.depth, rgb)
    return Pixels(rgb, usable, depth)


def joint_bilateral_upsample(depth: np.ndarray, guide_rgb: np.ndarray) -> np.ndarray:
    """Depth at the guide's size: nearest samples smoothed by a joint bilateral filter whose
    weights come from the full-size frame, so they do not average across its edges."""
    import kornia
    import torch

    h, w = guide_rgb.shape[:2]
    scale = max(w / depth.shape[1], h / depth.shape[0])
    valid = (np.isfinite(depth) & (depth > 0)).astype(np.float32)
    d = np.where(valid > 0, depth, 0).astype(np.float32)
    d_up = cv2.resize(d, (w, h), interpolation=cv2.INTER_NEAREST)
    v_up = cv2.resize(valid, (w, h), interpolation=cv2.INTER_NEAREST)
    if scale <= 1.0:
        return d_up
    grey = cv2.cvtColor(guide_rgb, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    radius = int(np.ceil(2 * scale))
    stack = torch.from_numpy(np.stack([d_up * v_up, v_up]))[:, None]  # (2, 1, H, W)
    guide = torch.from_numpy(grey)[None, None].expand(2, 1, h, w)
    with torch.no_grad():
        out = kornia.filters.joint_bilateral_blur(
            stack, guide, (2 * radius + 1, 2 * radius + 1), SIGMA_COLOR, (scale, scale)
        ).numpy()
    num, den = out[0, 0], out[1, 0]
    return np.where((v_up > 0) & (den > 1e-3), num / np.maximum(den, 1e-6), 0).astype(np.float32)


def source_size(case: CaseExport) -> tuple[int, int]:
    """(width, height) of the input's frames, from its first frame."""
    for frame in _open_source(case).frames():
        h, w = frame.rgb.shape[:2]
        return w, h
    raise EndopipeError(f"{case.case_dir.name}: the input has no frame to read")


def _open_source(case: CaseExport):  # -> InputSource
    """The input as ingest read it: its path and reader from the ingest view."""
    from endopipe.stages.ingest.view import IngestView
    from endopipe.stages.io.sources import open_input

    ingest = case.view("ingest", IngestView)
    src = ingest.file.source if ingest is not None else None
    if src is None:
        raise EndopipeError(
            f"{case.case_dir.name}: 01_ingest does not say where its input is; export at "
            "--resolution working"
        )
    path = Path(src.path)
    if not path.exists():
        raise EndopipeError(
            f"the input {path} is gone; --resolution source re-reads it (or use working)"
        )
    return open_input(path, format=src.kind)
