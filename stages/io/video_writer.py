"""Write RGB frames to an H.264 mp4 (PyAV), padding to even sizes as yuv420p requires."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np


def write_mp4(path: Path, frames: list[np.ndarray], fps: int = 10, crf: int = 18) -> None:
    """Write frames (HxWx3 uint8, same size) to `path` atomically (temp name, then rename)."""
    h, w = frames[0].shape[:2]
    ph, pw = h + h % 2, w + w % 2
    tmp = path.with_name(f".{path.name}.tmp.mp4")
    with av.open(str(tmp), "w") as container:
        stream = container.add_stream("libx264", rate=fps)
        stream.width, stream.height, stream.pix_fmt = pw, ph, "yuv420p"
        stream.options = {"crf": str(crf)}
        for rgb in frames:
            if (ph, pw) != (h, w):
                rgb = np.pad(rgb, ((0, ph - h), (0, pw - w), (0, 0)))
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    tmp.replace(path)
