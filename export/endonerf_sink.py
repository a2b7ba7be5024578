"""EndoNeRF's layout written frame by frame, for a case that is being made rather than one
that was run (`endopipe synth --layout endonerf`): the same files and conventions as the
`endonerf` export (`endonerf.py`, whose writers it uses), with the masks the scene's tools.

Depth is the exact z-depth, or with a right eye (`--stereo`) the depth the project's stereo
matcher finds on the rendered pair, as EndoNeRF's own depth/ was matched from its rig: then it
is a measurement with a measurement's holes and errors, and the exact truth stays in gt/.
Near / far per frame are the depth's 0.1 / 99.9 percentiles (LLFF's rule); the depth scale
(100 when the deepest value fits) needs the whole sequence, so the depth PNGs are written at
the end.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from endopipe.export.endonerf import (
    AXES_DOC,
    PINHOLE_ONLY,
    endonerf_depth_scale,
    frame_file,
    percentile_bounds,
    pinhole_notes,
    poses_bounds,
    write_depth_png,
    write_mask,
)
from endopipe.pipeline.stage import write_json
from endopipe.stages.camera import Camera
from endopipe.stages.ingest.config import StereoConfig
from endopipe.stages.ingest.stereo import match_depth
from endopipe.stages.ingest.stereo_frames import MATCHER


class EndoNerfSink:
    """images/, masks/ (255 = tool), depth/, poses_bounds.npy and endonerf.json in `out`.
    A lens the pinhole-only format cannot carry is refused here, before anything is rendered."""

    def __init__(
        self, out: Path, camera: Camera, axes: str = "llff", baseline_mm: float | None = None
    ) -> None:
        self.notes = pinhole_notes(camera)
        self.out, self.camera, self.axes = Path(out), camera, axes
        self.baseline = baseline_mm
        for sub in ("images", "masks", "depth"):
            (self.out / sub).mkdir(parents=True, exist_ok=True)
        self.depths: list[np.ndarray] = []

    def add_frame(
        self,
        rgb: np.ndarray,
        depth: np.ndarray,
        tool: np.ndarray | None,
        right: np.ndarray | None = None,
    ) -> None:
        n = len(self.depths)
        cv2.imwrite(str(frame_file(self.out, "images", n)), rgb[:, :, ::-1])
        excluded = np.zeros(depth.shape, bool) if tool is None else tool
        write_mask(self.out, n, excluded)
        if self.baseline is not None:
            if right is None:
                raise ValueError("a stereo EndoNeRF case needs every frame's right eye")
            depth = match_depth(rgb, right, self.camera.fx, self.baseline, StereoConfig())
        self.depths.append(depth.astype(np.float32))

    def finish(self, poses: np.ndarray) -> None:
        k = self.camera
        deepest = max((float(d.max()) for d in self.depths if d.size), default=0.0)
        scale = endonerf_depth_scale(deepest)
        for n, d in enumerate(self.depths):
            write_depth_png(self.out, n, d, scale)
        bounds = [percentile_bounds(d[d > 0]) for d in self.depths]
        hwf = (float(k.height), float(k.width), float(k.fx))
        np.save(self.out / "poses_bounds.npy", poses_bounds(list(poses), hwf, bounds, self.axes))
        write_json(
            self.out / "endonerf.json",
            {
                "axes": self.axes,
                "columns": AXES_DOC[self.axes],
                "depth_scale": scale,
                "bounds": "depth maps",
                "camera": PINHOLE_ONLY,
                "masks": "255 = tool (excluded), 0 = tissue",
                "units": "mm",
                "depth": "exact synthetic truth"
                if self.baseline is None
                else f"{MATCHER} on the rendered pair, baseline {self.baseline:g} mm",
                "notes": self.notes,
            },
        )
