"""Writes an endopipe case folder (docs/formats.md) frame by frame, then the whole-sequence files.

Everything goes to a temporary sibling folder that is renamed into place at the end, so an
interrupted run never leaves something that looks like a finished case.
"""

from __future__ import annotations

import json
import shutil
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np
import trimesh

from endopipe.stages.camera import Camera

FPS = 15
CRF = 14
MARKER = "gt/synth.json"  # written last; marks a folder as a synth case we may replace


def _yuv_frame(rgb: np.ndarray) -> av.VideoFrame:
    """RGB -> yuv420p frame whose row padding is filled (edge pixels), not left uninitialised:
    x264 reads some of the padding, and garbage there made the video differ from run to run."""
    src = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
    src = src.reformat(format="yuv420p")
    out = av.VideoFrame(src.width, src.height, "yuv420p")
    for a, b in zip(src.planes, out.planes, strict=True):
        h, w = a.height, a.width
        pixels = np.frombuffer(a, np.uint8).reshape(-1, a.line_size)[:h, :w]
        dst = np.frombuffer(b, np.uint8).reshape(-1, b.line_size)
        dst[:h, :w] = pixels
        dst[:h, w:] = pixels[:, -1:]
        dst[h:] = dst[h - 1]
    return out


class CaseWriter:
    """Streams frames into video.mp4, frames/*.png and gt/, then publishes the folder."""

    def __init__(self, out: Path, intr: Camera, fps: int = FPS) -> None:
        self.out = Path(out)
        if self.out.exists() and any(self.out.iterdir()) and not (self.out / MARKER).exists():
            raise FileExistsError(f"{self.out} exists and is not a synth case; refusing to replace")
        self.out.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = self.out.parent / f".{self.out.name}.synth-tmp"
        if self.tmp.exists():
            shutil.rmtree(self.tmp)
        for sub in ("frames", "gt/depth", "gt/specular"):
            (self.tmp / sub).mkdir(parents=True)
        # intrinsics.json as stages/io reads it: `model` and `dist` for a distorted lens.
        self._write_json(
            "intrinsics.json", intr.model_dump(exclude=None if intr.distorted else {"dist"})
        )
        self.intr = intr
        self.count = 0
        self._container = av.open(str(self.tmp / "video.mp4"), mode="w")
        stream = self._container.add_stream("libx264", rate=fps)
        stream.width, stream.height, stream.pix_fmt = intr.width, intr.height, "yuv420p"
        # Reproducible bitstream: one encoder thread (slice threads would tie it to the core
        # count) and no macroblock-tree rate control (x264's mbtree read uninitialised memory
        # here: outputs differed between identical runs). Costs little at this size and CRF.
        stream.options = {"crf": str(CRF), "preset": "medium", "x264-params": "mbtree=0"}
        stream.codec_context.thread_count = 1
        stream.codec_context.thread_type = "NONE"
        stream.codec_context.time_base = Fraction(1, fps)
        self._stream, self.fps = stream, fps

    def _write_json(self, rel: str, obj: object) -> None:
        (self.tmp / rel).write_text(json.dumps(obj, indent=1))

    def add_frame(self, rgb: np.ndarray, depth: np.ndarray, specular: np.ndarray) -> None:
        """One frame: its image (HxWx3 uint8), exact z-depth (mm, 0 = miss), specular mask."""
        name = f"{self.count:06d}"
        cv2.imwrite(str(self.tmp / "frames" / f"{name}.png"), rgb[:, :, ::-1])
        np.save(self.tmp / "gt" / "depth" / f"{name}.npy", depth.astype(np.float32))
        mask = np.where(specular, 255, 0).astype(np.uint8)
        cv2.imwrite(str(self.tmp / "gt" / "specular" / f"{name}.png"), mask)
        frame = _yuv_frame(rgb)
        frame.pts = self.count
        frame.time_base = Fraction(1, self.fps)
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self.count += 1

    def finish(
        self,
        poses: np.ndarray,
        mesh: tuple[np.ndarray, np.ndarray],
        centerline: tuple[np.ndarray, np.ndarray],
        meta: dict,
    ) -> None:
        """Close the video, write poses, mesh, centre line and metadata, publish the folder."""
        for packet in self._stream.encode():
            self._container.mux(packet)
        self._container.close()
        self._write_json(
            "gt/poses.json",
            {"convention": "opencv_c2w", "units": "mm", "poses": poses.tolist()},
        )
        verts, faces = mesh
        tm = trimesh.Trimesh(vertices=verts.astype(np.float32), faces=faces, process=False)
        tm.export(self.tmp / "gt" / "mesh.ply")
        points, radius = centerline
        self._write_json(
            "gt/centerline.json",
            {"points": np.round(points, 6).tolist(), "radius": np.round(radius, 6).tolist()},
        )
        self._write_json(MARKER, meta)
        if self.out.exists():
            shutil.rmtree(self.out)
        self.tmp.rename(self.out)

    def abort(self) -> None:
        """Drop the temporary folder after a failure."""
        try:
            self._container.close()
        except Exception:  # noqa: BLE001 - best effort on the way out of an error
            pass
        shutil.rmtree(self.tmp, ignore_errors=True)
