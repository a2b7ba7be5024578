"""A SCARED keyframe written frame by frame (`endopipe synth --layout scared [--stereo]`): what
stages/io/scared.py reads.

```
endoscope_calibration.yaml      M1 = M2 (the synthetic camera), D1 = D2 (its lens, OpenCV's
                                five), R = I, T = (-baseline, 0, 0) mm; no stereo: T = (-1, 0, 0)
left_depth_map.tiff             float32 x, y, z (mm) of each left pixel of the first frame
Left_Image.png, Right_Image.png the first frame's two eyes (--stereo; the left alone without)
data/rgb.mp4                    left over right (--stereo), else the left eye alone
data/frame_data/frame_dataNNNNNN.json   {"camera-pose": the left camera's c2w (mm)}
```

The right eye is the left camera moved along its +x (a rectified pair), so the rig's rectifying
rotations are the identity. A fisheye lens cannot be written in SCARED's OpenCV distortion.
"""

from __future__ import annotations

import json
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np
import tifffile

from endopipe.pipeline.errors import EndopipeError
from endopipe.stages.camera import Camera, backproject
from endopipe.stages.io.scared import (
    CALIBRATION,
    FRAME_DATA,
    KEYFRAME_DEPTH,
    LEFT_IMAGE,
    RIGHT_IMAGE,
    VIDEO,
)

FPS = 25
CRF = 14


class ScaredSink:
    """The keyframe folder, its video encoded as the frames come."""

    #: The data set, as the refusal of a fisheye names it, the folders made first and the video.
    title = "SCARED"
    folders: tuple[str, ...] = (FRAME_DATA,)
    video = VIDEO

    def __init__(self, out: Path, camera: Camera, baseline_mm: float | None = None) -> None:
        if camera.model == "fisheye" and camera.distorted:
            raise EndopipeError(
                f"{self.title}'s calibration holds OpenCV's radial-tangential lens, not a "
                "fisheye: use --lens pinhole or barrel"
            )
        self.out, self.camera, self.baseline = Path(out), camera, baseline_mm
        for folder in self.folders:
            (self.out / folder).mkdir(parents=True, exist_ok=True)
        self._write_calibration()
        self.container: av.container.OutputContainer | None = None
        self.count = 0

    def _write_calibration(self) -> None:
        k = self.camera
        K = np.array([[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]])
        D = np.zeros((1, 5))
        D[0, : len(k.coefficients())] = k.coefficients()
        fs = cv2.FileStorage(str(self.out / CALIBRATION), cv2.FILE_STORAGE_WRITE)
        for name, m in (("M1", K), ("D1", D), ("M2", K), ("D2", D), ("R", np.eye(3))):
            fs.write(name, m)
        fs.write("T", np.array([[-(self.baseline or 1.0)], [0.0], [0.0]]))
        fs.release()

    def _stream(self, width: int, height: int) -> av.video.stream.VideoStream:
        self.container = av.open(str(self.out / self.video), mode="w")
        stream = self.container.add_stream("libx264", rate=FPS)
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = {"crf": str(CRF), "preset": "medium", "x264-params": "mbtree=0"}
        stream.codec_context.thread_count = 1
        stream.codec_context.time_base = Fraction(1, FPS)
        self.stream = stream
        return stream

    def add_frame(
        self,
        rgb: np.ndarray,
        depth: np.ndarray,
        tool: np.ndarray | None,
        right: np.ndarray | None = None,
    ) -> None:
        if self.container is None:
            points = backproject(self.camera, depth).reshape(depth.shape + (3,))
            points[depth <= 0] = 0.0
            tifffile.imwrite(
                str(self.out / KEYFRAME_DEPTH), points.astype(np.float32), photometric="rgb"
            )
            for name, eye in ((LEFT_IMAGE, rgb), (RIGHT_IMAGE, right)):
                if eye is not None:
                    cv2.imwrite(str(self.out / name), cv2.cvtColor(eye, cv2.COLOR_RGB2BGR))
        self._encode(rgb, right)

    def _encode(self, rgb: np.ndarray, right: np.ndarray | None) -> None:
        """One frame of the video: the left eye over the right (the left alone without one)."""
        image = rgb if right is None else np.concatenate([rgb, right], axis=0)
        if self.container is None:
            self._stream(image.shape[1], image.shape[0])
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="rgb24")
        frame.pts = self.count
        for packet in self.stream.encode(frame):
            self.container.mux(packet)
        self.count += 1

    def _close(self) -> None:
        if self.container is not None:
            for packet in self.stream.encode():
                self.container.mux(packet)
            self.container.close()

    def finish(self, poses: np.ndarray) -> None:
        self._close()
        for n, pose in enumerate(poses):
            data = {"camera-pose": np.asarray(pose).tolist()}
            (self.out / FRAME_DATA / f"frame_data{n:06d}.json").write_text(json.dumps(data))


def spoil_calibration(keyframe: Path, turn_deg: tuple[float, float, float], half: bool) -> None:
    """Spoil a keyframe's calibration in place as real releases are: its R turned by `turn_deg`
    (a rotation vector, degrees: a tilt about the rows' axis, a toe-in about the columns', a
    roll about the optical axis) and, when `half`, M1 and M2 stated for half the image size."""
    file = Path(keyframe) / CALIBRATION
    fs = cv2.FileStorage(str(file), cv2.FILE_STORAGE_READ)
    m = {k: fs.getNode(k).mat() for k in ("M1", "D1", "M2", "D2", "R", "T")}
    fs.release()
    turn, _ = cv2.Rodrigues(np.radians(np.asarray(turn_deg, np.float64)))
    m["R"] = turn @ m["R"]
    if half:
        for name in ("M1", "M2"):
            k = m[name].copy()
            k[:2, :2] /= 2
            k[:2, 2] = (k[:2, 2] + 0.5) / 2 - 0.5  # the pixel-centre convention, at half size
            m[name] = k
    fs = cv2.FileStorage(str(file), cv2.FILE_STORAGE_WRITE)
    for name, value in m.items():
        fs.write(name, value)
    fs.release()
