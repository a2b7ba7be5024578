"""A StereoMIS sequence written frame by frame (`endopipe synth --layout stereomis [--stereo]`):
what stages/io/stereomis.py reads.

```
StereoCalibration.ini   [StereoLeft] = [StereoRight]: the synthetic camera (res_x, res_y, fc_x,
                        fc_y, cc_x, cc_y; kc_0..kc_4 its lens, OpenCV's five, kc_5..kc_7 0);
                        [StereoRight] R = I, T = (-baseline, 0, 0) mm; no stereo: T = (-1, 0, 0)
stereomis.mp4           left over right (--stereo), else the left eye alone
groundtruth.txt         TUM: "timestamp tx ty tz qx qy qz qw" a frame, the left camera's c2w (m)
masks/NNNNNNl.png       the left eye's mask, 255 = tissue, 0 = the tool (StereoMIS's polarity)
```

The right eye is the left camera moved along its +x (a rectified pair), so the rig's rectifying
rotations are the identity. The video is not named video.mp4: beside `gt/` that name would make
the folder an endopipe case folder. A fisheye lens cannot be written in OpenCV's eight
coefficients.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from endopipe.stages.io.stereomis import CALIBRATION, LEFT, POSES, RIGHT
from endopipe.synth.scared_sink import FPS, ScaredSink

VIDEO = "stereomis.mp4"
MASKS = "masks"


def number(value: float) -> str:
    """A value as the ini holds it: an integer as one, else every digit of a float."""
    return str(value) if isinstance(value, int) else repr(float(value))


class StereoMISSink(ScaredSink):
    """The sequence folder, its video encoded as the frames come (ScaredSink's encoder)."""

    title = "StereoMIS"
    folders = (MASKS,)
    video = VIDEO

    def _write_calibration(self) -> None:
        k = self.camera
        eye = {"res_x": k.width, "res_y": k.height, "fc_x": k.fx, "fc_y": k.fy}
        eye |= {"cc_x": k.cx, "cc_y": k.cy}
        dist = np.zeros(8)
        dist[: len(k.coefficients())] = k.coefficients()
        eye |= {f"kc_{i}": c for i, c in enumerate(dist)}
        right = dict(eye)
        right |= {f"R_{i}": v for i, v in enumerate(np.eye(3).ravel())}
        right |= {"T_0": -(self.baseline or 1.0), "T_1": 0.0, "T_2": 0.0}
        lines = []
        for name, values in ((LEFT, eye), (RIGHT, right)):
            lines += [f"[{name}]", *(f"{key} = {number(v)}" for key, v in values.items()), ""]
        (self.out / CALIBRATION).write_text("\n".join(lines))

    def add_frame(
        self,
        rgb: np.ndarray,
        depth: np.ndarray,
        tool: np.ndarray | None,
        right: np.ndarray | None = None,
    ) -> None:
        keep = np.full(rgb.shape[:2], 255, np.uint8)
        if tool is not None:
            keep[np.asarray(tool, bool)] = 0
        cv2.imwrite(str(self.out / MASKS / f"{self.count:06d}l.png"), keep)
        self._encode(rgb, right)

    def finish(self, poses: np.ndarray) -> None:
        self._close()
        rows = ["# timestamp tx ty tz qx qy qz qw (the left camera's c2w, metres)"]
        for n, pose in enumerate(np.asarray(poses, np.float64)):
            t = pose[:3, 3] / 1000.0
            q = Rotation.from_matrix(pose[:3, :3]).as_quat()  # x y z w
            rows.append(" ".join(repr(float(v)) for v in (n / FPS, *t, *q)))
        (self.out / POSES).write_text("\n".join(rows) + "\n")
