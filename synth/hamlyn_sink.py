"""The rectified Hamlyn release's layout written frame by frame (`endopipe synth --layout hamlyn
[--stereo]`): what stages/io/hamlyn.py reads, so a synthetic stereo sequence goes through the
same reader as a downloaded one.

```
image01/0000000000.jpg   left eye (JPEG, as released)
image02/0000000000.jpg   right eye, --stereo only: the left camera moved by the baseline along +x
depth01/0000000000.png   uint16 z-depth in mm of the left eye: the exact truth rounded to 1 mm
intrinsics.txt           the rectified left camera, 3x3 (both eyes share it)
extrinsics.txt           --stereo only: the right camera's [R | t] (3x4, t in mm; X_right =
                         R X_left + t, so t = (-baseline, 0, 0)), as calibration/NN/ ships it
```

A rectified pair is pinhole: a lens is refused before anything is rendered.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from endopipe.pipeline.errors import EndopipeError
from endopipe.stages.camera import Camera

JPEG_QUALITY = 95
UINT16_MAX = 65535


def name(n: int, suffix: str) -> str:
    """The release's file names: the frame number padded to ten digits."""
    return f"{n:010d}{suffix}"


def refuse_lens(camera: Camera, layout: str) -> None:
    """Rectified images have no lens left: one line instead of images that lie about it."""
    if camera.distorted:
        raise EndopipeError(
            f"the {layout} layout holds rectified images, which have no lens; this camera's "
            f"{camera.model} lens {camera.dist} cannot be written to it: use --lens pinhole"
        )


def matrix_text(m: np.ndarray) -> str:
    return "".join(" ".join(f"{v:.10g}" for v in row) + "\n" for row in m)


def camera_matrix(camera: Camera) -> np.ndarray:
    return np.array([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]])


def depth_png(depth: np.ndarray) -> np.ndarray:
    """z-depth (mm, 0 = none) as uint16 whole millimetres."""
    return np.clip(np.round(depth), 0, UINT16_MAX).astype(np.uint16)


def write_jpeg(path: Path, rgb: np.ndarray) -> None:
    cv2.imwrite(str(path), rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])


class HamlynSink:
    """image01/, image02/ (stereo), depth01/, intrinsics.txt and extrinsics.txt in `out`."""

    def __init__(self, out: Path, camera: Camera, baseline_mm: float | None = None) -> None:
        refuse_lens(camera, "hamlyn")
        self.out, self.baseline = Path(out), baseline_mm
        for sub in ("image01", "depth01") + (("image02",) if baseline_mm else ()):
            (self.out / sub).mkdir(parents=True, exist_ok=True)
        (self.out / "intrinsics.txt").write_text(matrix_text(camera_matrix(camera)))
        self.count = 0

    def add_frame(
        self,
        rgb: np.ndarray,
        depth: np.ndarray,
        tool: np.ndarray | None,
        right: np.ndarray | None = None,
    ) -> None:
        n = self.count
        write_jpeg(self.out / "image01" / name(n, ".jpg"), rgb)
        if self.baseline is not None:
            if right is None:
                raise ValueError("a stereo Hamlyn sequence needs every frame's right eye")
            write_jpeg(self.out / "image02" / name(n, ".jpg"), right)
        cv2.imwrite(str(self.out / "depth01" / name(n, ".png")), depth_png(depth))
        self.count += 1

    def finish(self, poses: np.ndarray) -> None:
        if self.baseline is None:
            return
        rt = np.hstack([np.eye(3), [[-self.baseline], [0.0], [0.0]]])
        (self.out / "extrinsics.txt").write_text(matrix_text(rt))
