"""C3VD v3's "aligned review preview" frames (../shared/data/c3vd_v3_preview): real colonoscope
frames with the registered depth render as an 8-bit grey panel, read in place.

```
c3vd_v3_preview/
  rgb/NNNN.png              colonoscope frames (source_index = position in numeric order)
  depth_vis_gray/NNNN.png   depth panel: brighter = farther, unknown normalisation, H.264
  occlusion/NNNN.png        (not used)
```

The grey panel is an affine proxy of depth at best (its normalisation is unknown and it went
through a video codec), so its ground truth is `kind = "relative"`: evaluation may compare only
up to scale and shift (or by rank), never in millimetres. No intrinsics and no poses ship.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.frame_truth import NumberedGroundTruth, numbered
from endopipe.stages.io.images import ImageListSource
from endopipe.stages.io.intrinsics import load_intrinsics_file

NAME = "c3vd_preview"
LAYOUT = "rgb/NNNN.png with depth_vis_gray/NNNN.png (relative depth only)"
GT_KIND = "relative"
NUMBERED = re.compile(r"^(\d+)\.png$", re.IGNORECASE)
# The codec smears the panel's edge against its unrendered (0) region: grey levels within 3 px
# of it ramp from 0 to the wall's value (median 2 at 1 px, 12-17 at 2 px, 26-31 at 3-4 px, the
# wall 32-36 beyond, frames 5/35/65). They are no depth, and as a divisor in AbsRel a grey 2
# outweighs a hundred true pixels, so they count as invalid.
CODEC_EDGE_PX = 3.0


def is_sequence(path: Path) -> bool:
    path = Path(path)
    return bool(numbered(path / "rgb", NUMBERED)) and (path / "depth_vis_gray").is_dir()


class C3VDPreviewGroundTruth(NumberedGroundTruth):
    """The grey depth panel per frame, as float32 grey levels (0 = invalid): relative only."""

    dataset = NAME
    kind = GT_KIND
    units = "relative"
    title = "C3VD preview"
    frame_pattern = NUMBERED
    depth_pattern = NUMBERED
    frame_folder = "rgb"
    depth_folder = "depth_vis_gray"
    read_flag = cv2.IMREAD_GRAYSCALE

    def __init__(self, seq: Path) -> None:
        super().__init__(seq)
        # The panel is one column wider than the RGB panel (447 vs 446): depth is cropped to the
        # frames' width, read once (every frame of the video has the same size).
        first = cv2.imread(str(self.frames[0])) if self.frames else None
        self._width = first.shape[1] if first is not None else None

    def decode_depth(self, raw: np.ndarray) -> np.ndarray:
        if self._width is not None and raw.shape[1] > self._width:
            raw = raw[:, : self._width]
        return without_codec_edge(raw).astype(np.float32)  # 0 = invalid (docs/formats.md)


def without_codec_edge(panel: np.ndarray) -> np.ndarray:
    """The grey panel with 0 (no render) and every pixel within `CODEC_EDGE_PX` of a 0 set to
    0: there the codec blended the wall's grey with the black outside, so the value is no
    depth."""
    rendered = (panel > 0).astype(np.uint8)
    if rendered.all():
        return panel
    distance = cv2.distanceTransform(rendered, cv2.DIST_L2, 5)
    return np.where(distance > CODEC_EDGE_PX, panel, 0).astype(panel.dtype)


class C3VDPreviewSource(ImageListSource):
    kind = NAME
    truth = C3VDPreviewGroundTruth


def open_sequence(path: Path, intrinsics: Camera | None = None) -> C3VDPreviewSource:
    path = Path(path)
    frames = numbered(path / "rgb", NUMBERED)
    if not frames:
        raise InputError(f"{path} is not a C3VD preview folder ({LAYOUT})")
    if intrinsics is None and (path / "intrinsics.json").is_file():
        intrinsics = load_intrinsics_file(path / "intrinsics.json")
    return C3VDPreviewSource(path, [f for _, f in frames], intrinsics, path)


def ground_truth(path: Path) -> C3VDPreviewGroundTruth:
    return C3VDPreviewGroundTruth(path)
