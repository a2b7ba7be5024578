"""A video file as frames, with its damage (unreadable, truncated) said in one line."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import av

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.input_source import Frame, InputSource
from endopipe.stages.io.messages import HINT, short_reason

VIDEO_SUFFIXES = {".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg"}


class VideoSource(InputSource):
    kind = "video"

    def __init__(self, path: Path, intrinsics: Camera | None, gt_dir: Path | None) -> None:
        super().__init__(path, intrinsics, gt_dir)
        self._probe()

    def _open(self) -> av.container.InputContainer:
        try:
            container = av.open(str(self.path))
        except (av.FFmpegError, UnicodeDecodeError, OSError) as e:
            raise InputError(
                f"cannot read {self.path} as a video ({short_reason(e)}); is the file complete? "
                f"{HINT}"
            ) from None
        if not container.streams.video:
            container.close()
            raise InputError(f"{self.path} has no video stream; {HINT}")
        return container

    def _probe(self) -> None:
        container = self._open()
        stream = container.streams.video[0]
        self.fps = float(stream.average_rate or stream.guessed_rate or 25.0)
        self._declared = int(stream.frames or 0)
        container.close()

    def frame_count(self) -> int | None:
        return self._declared or None

    def frames(self) -> Iterator[Frame]:
        container = self._open()
        index = 0
        try:
            for frame in container.decode(video=0):
                t = float(frame.time) if frame.time is not None else index / self.fps
                yield Frame(index, t, frame.to_ndarray(format="rgb24"))
                index += 1
        except av.FFmpegError as e:
            raise InputError(
                f"video {self.path} is damaged after frame {index} ({short_reason(e)}); "
                "re-export it or trim it with --set ingest.end_s=..."
            ) from None
        finally:
            container.close()
        if self._declared and index < self._declared * 0.9:
            raise InputError(
                f"video {self.path} is truncated: its header declares {self._declared} frames "
                f"but only {index} decode; re-export or re-download it"
            )
