"""The Hamlyn release of Endo-Depth-and-Motion (EDaM) written frame by frame (`endopipe synth
--layout edam`): what its loader and stages/io/hamlyn.py read.

```
color/0000000000.jpg            the frames (JPEG)
depth/0000000000.png            uint16 z-depth in mm, saturated at 300 mm as the release's
                                stereo network's depth is (deeper pixels read 300)
intrinsic/intrinsic_color.txt   4x4 (ScanNet's layout, as EDaM's loader reads it), and
                                intrinsic_depth.txt, extrinsic_color.txt, extrinsic_depth.txt
                                (identity: depth is registered to colour)
```

EDaM ships no right images, so a stereo case is not written in this layout.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from endopipe.stages.camera import Camera
from endopipe.synth.hamlyn_sink import (
    camera_matrix,
    depth_png,
    matrix_text,
    name,
    refuse_lens,
    write_jpeg,
)

#: The release's saturation depth (its README): nothing deeper is written.
CEILING_MM = 300.0


class EdamSink:
    """color/, depth/ (300 mm ceiling) and intrinsic/ in `out`."""

    def __init__(self, out: Path, camera: Camera) -> None:
        refuse_lens(camera, "edam")
        self.out = Path(out)
        for sub in ("color", "depth", "intrinsic"):
            (self.out / sub).mkdir(parents=True, exist_ok=True)
        k = np.eye(4)
        k[:3, :3] = camera_matrix(camera)
        for file, m in (
            ("intrinsic_color.txt", k),
            ("intrinsic_depth.txt", k),
            ("extrinsic_color.txt", np.eye(4)),
            ("extrinsic_depth.txt", np.eye(4)),
        ):
            (self.out / "intrinsic" / file).write_text(matrix_text(m))
        self.count = 0

    def add_frame(self, rgb: np.ndarray, depth: np.ndarray, tool: np.ndarray | None) -> None:
        n = self.count
        write_jpeg(self.out / "color" / name(n, ".jpg"), rgb)
        saturated = np.where(depth > 0, np.minimum(depth, CEILING_MM), 0.0)
        cv2.imwrite(str(self.out / "depth" / name(n, ".png")), depth_png(saturated))
        self.count += 1

    def finish(self, poses: np.ndarray) -> None:
        """Nothing to add: EDaM's release has no poses."""
