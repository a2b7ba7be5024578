"""Writes an endopipe case folder (docs/formats.md) frame by frame, then the whole-sequence files.

Everything goes to a temporary sibling folder that is renamed into place at the end, so an
interrupted run never leaves something that looks like a finished case. Another tool's layout
(`Layout`: e.g. EndoNeRF's, written by the export library) may be written beside it, or instead
of the frames (the ground truth in gt/ is always written).
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Protocol

import av
import cv2
import numpy as np
import trimesh

from endopipe.stages.camera import Camera

FPS = 15
CRF = 14
MARKER = "gt/synth.json"  # written last; marks a folder as a synth case we may replace


class LayoutSink(Protocol):
    """Another tool's layout, fed frame by frame as the case is rendered."""

    def add_frame(
        self,
        rgb: np.ndarray,
        depth: np.ndarray,
        tool: np.ndarray | None,
        right: np.ndarray | None = None,
    ) -> None:
        """One frame: image (HxWx3 uint8 RGB), z-depth (mm, 0 = none), tool mask or None, and
        the right eye's image of a stereo case (given only to a layout that `takes_right`)."""

    def finish(self, poses: np.ndarray) -> None:
        """The OpenCV c2w poses (N, 4, 4) of every frame, mm; after the last frame."""


@dataclass(frozen=True)
class Layout:
    """Where and how another layout is written: `make(folder, camera)` opens its sink in
    `subfolder` of the case (\"\": the case folder itself, in place of endopipe's frames)."""

    name: str
    make: Callable[[Path, Camera], LayoutSink]
    subfolder: str = ""
    #: The layout has a place for a right eye (a stereo case's second image per frame).
    takes_right: bool = False


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

    def __init__(
        self, out: Path, intr: Camera, fps: int = FPS, layout: Layout | None = None
    ) -> None:
        self.out = Path(out)
        if self.out.exists() and any(self.out.iterdir()) and not (self.out / MARKER).exists():
            raise FileExistsError(f"{self.out} exists and is not a synth case; refusing to replace")
        self.out.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = self.out.parent / f".{self.out.name}.synth-tmp"
        if self.tmp.exists():
            shutil.rmtree(self.tmp)
        for sub in ("frames", "gt/depth", "gt/specular"):
            (self.tmp / sub).mkdir(parents=True)
        self.intr = intr
        self.count = 0
        self.sink: LayoutSink | None = None
        # endopipe's own frames (video, frames/, masks/, intrinsics.json) unless another layout
        # takes the case folder's place.
        self.frames = layout is None or layout.subfolder != ""
        if layout is not None:
            (self.tmp / layout.subfolder).mkdir(parents=True, exist_ok=True)
            try:
                self.sink = layout.make(self.tmp / layout.subfolder, intr)
            except BaseException:
                shutil.rmtree(self.tmp, ignore_errors=True)
                raise
        if not self.frames:
            (self.tmp / "frames").rmdir()
            self._container = None
            return
        # intrinsics.json as stages/io reads it: `model` and `dist` for a distorted lens.
        self._write_json(
            "intrinsics.json", intr.model_dump(exclude=None if intr.distorted else {"dist"})
        )
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

    def add_frame(
        self,
        rgb: np.ndarray,
        depth: np.ndarray,
        specular: np.ndarray,
        tool: np.ndarray | None = None,
        right: np.ndarray | None = None,
    ) -> None:
        """One frame: its image (HxWx3 uint8), exact z-depth (mm, 0 = miss), specular mask,
        where a tool covers it (masks/, 255 = tool: EndoNeRF's polarity) when one is in the
        scene, and the right eye's image of a stereo case (to the layout's sink only)."""
        name = f"{self.count:06d}"
        np.save(self.tmp / "gt" / "depth" / f"{name}.npy", depth.astype(np.float32))
        mask = np.where(specular, 255, 0).astype(np.uint8)
        cv2.imwrite(str(self.tmp / "gt" / "specular" / f"{name}.png"), mask)
        if self.sink is not None and right is not None:
            self.sink.add_frame(rgb, depth, tool, right=right)
        elif self.sink is not None:  # a sink without a place for a right eye takes three
            self.sink.add_frame(rgb, depth, tool)
        if not self.frames:
            self.count += 1
            return
        cv2.imwrite(str(self.tmp / "frames" / f"{name}.png"), rgb[:, :, ::-1])
        if tool is not None:
            (self.tmp / "masks").mkdir(exist_ok=True)
            cv2.imwrite(str(self.tmp / "masks" / f"{name}.png"), tool_mask_png(tool))
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
        if self._container is not None:
            for packet in self._stream.encode():
                self._container.mux(packet)
            self._container.close()
        surface = getattr(self.sink, "add_surface", None)
        if callable(surface):  # a layout that ships the scene's surface (C3VD's model mesh)
            surface(*mesh)
        if self.sink is not None:
            self.sink.finish(poses)
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
            if self._container is not None:
                self._container.close()
        except Exception:  # noqa: BLE001 - best effort on the way out of an error
            pass
        shutil.rmtree(self.tmp, ignore_errors=True)


def tool_mask_png(tool: np.ndarray) -> np.ndarray:
    """A tool mask as written: uint8, 255 = tool, 0 = tissue (EndoNeRF's polarity)."""
    return np.where(tool, 255, 0).astype(np.uint8)
