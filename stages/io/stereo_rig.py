"""A calibrated stereo rig and the video that holds both its eyes: what the readers of the da
Vinci stereo sets (SCARED, StereoMIS) share.

Both ship one video whose frames are the left eye over the right (a frame wider than tall is
one eye only), and a calibration of the unrectified pair (both eyes' matrices and lenses, the
right camera's R and T from the left, mm). The frames are rectified with cv2.stereoRectify
(alpha 0: no black border, principal points made equal): the input's intrinsics are P1's
pinhole, the right eye is the input's `StereoPairs` (baseline from P2), and a pose of the left
camera is turned by R1 into the rectified camera's.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import av
import cv2
import numpy as np

from endopipe.pipeline.cache import digest_path, digest_text
from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.calibration_check import fit_to_frames
from endopipe.stages.io.input_source import Frame, InputSource
from endopipe.stages.io.messages import short_reason
from endopipe.stages.io.stereo_pairs import StereoPairs


@dataclass(frozen=True)
class Rig:
    """The calibrated pair and its rectification at one image size."""

    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    size: tuple[int, int]  # width, height of one eye
    said: str | None = None  # the calibration rescaled to this size, in one line

    @cached_property
    def rectified(self) -> tuple[np.ndarray, ...]:
        """R1, R2, P1, P2 of cv2.stereoRectify (alpha 0, principal points made equal)."""
        R1, R2, P1, P2, *_ = cv2.stereoRectify(
            self.K1, self.D1, self.K2, self.D2, self.size, self.R, self.T, alpha=0
        )
        return R1, R2, P1, P2

    @cached_property
    def maps(self) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
        R1, R2, P1, P2 = self.rectified
        left = cv2.initUndistortRectifyMap(self.K1, self.D1, R1, P1, self.size, cv2.CV_32FC1)
        right = cv2.initUndistortRectifyMap(self.K2, self.D2, R2, P2, self.size, cv2.CV_32FC1)
        return left, right

    def camera(self) -> Camera:
        P1 = self.rectified[2]
        w, h = self.size
        return Camera(width=w, height=h, fx=P1[0, 0], fy=P1[1, 1], cx=P1[0, 2], cy=P1[1, 2])

    def baseline_mm(self) -> float:
        P2 = self.rectified[3]
        return float(abs(P2[0, 3] / P2[0, 0]))

    def rectified_poses(self, poses: list[np.ndarray]) -> list[np.ndarray]:
        """The left camera's c2w poses as the rectified left camera's: X_cam = R1^T X_rect."""
        turn = np.eye(4)
        turn[:3, :3] = self.rectified[0].T
        return [p @ turn for p in poses]


def fitted_to_eyes(
    K1: np.ndarray, K2: np.ndarray, size: tuple[int, int], source: str
) -> tuple[np.ndarray, np.ndarray, str | None]:
    """Both eyes' matrices checked against the images' size (calibration_check.py): stated
    for another size, both are brought to this one, and the line says so."""
    fit = fit_to_frames(camera_of(K1, size), source)
    if fit.said is None or fit.camera.fx == K1[0, 0]:
        return K1, K2, fit.said
    factor = fit.camera.fx / K1[0, 0]
    return (
        matrix_of(fit.camera),
        matrix_of(camera_of(K2, size).zoomed(factor, factor, *size)),
        fit.said,
    )


def own_calibration_only(
    path: Path, found: bool, what: str, layout: str, intrinsics: Camera | None
) -> None:
    """A stereo data set's folder (`found`: its files are there), opened with no intrinsics
    of the user's (its frames are rectified with its own calibration): one InputError line."""
    if not found:
        raise InputError(f"{path} is not a {what} ({layout})")
    if intrinsics is not None:
        raise InputError(
            f"{what}'s frames are rectified with its own calibration; drop --intrinsics"
        )


def camera_of(K: np.ndarray, size: tuple[int, int]) -> Camera:
    """A 3x3 camera matrix as the pinhole camera of images of `size` (width, height)."""
    return Camera(width=size[0], height=size[1], fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2])


def matrix_of(k: Camera) -> np.ndarray:
    return np.array([[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]])


def video_size(video: Path) -> tuple[int, int]:
    """(width, height) of a video's frames; one InputError line when it is not a video."""
    try:
        with av.open(str(video)) as container:
            stream = container.streams.video[0]
            return int(stream.width), int(stream.height)
    except (av.FFmpegError, IndexError, OSError) as e:
        raise InputError(f"cannot read {video} ({short_reason(e)})") from None


def eye_size(frame_size: tuple[int, int]) -> tuple[tuple[int, int], bool]:
    """One eye's (width, height) and whether the frames hold both (taller than wide)."""
    w, h = frame_size
    stacked = h > w
    return ((w, h // 2) if stacked else (w, h)), stacked


class StackedVideo(InputSource):
    """The rectified left eye of a video whose frames hold the left eye over the right (or the
    left eye alone), frame by frame; `stereo_pairs()` gives the rectified right eye."""

    def __init__(
        self,
        path: Path,
        video: Path,
        calibration: Path,
        rig: Rig,
        stacked: bool,
        gt_dir: Path | None,
    ) -> None:
        super().__init__(path, rig.camera(), gt_dir)
        self.video, self.calibration = video, calibration
        self.rig, self.stacked = rig, stacked
        self.fps = 25.0

    def _eyes(self) -> Iterator[tuple[int, float | None, np.ndarray, np.ndarray | None]]:
        """(index, time, left, right or None), unrectified, in order."""
        w, h = self.rig.size
        try:
            with av.open(str(self.video)) as container:
                stream = container.streams.video[0]
                self.fps = float(stream.average_rate or 25.0)
                for i, frame in enumerate(container.decode(video=0)):
                    rgb = frame.to_ndarray(format="rgb24")
                    t = float(frame.time) if frame.time is not None else i / self.fps
                    yield i, t, rgb[:h, :w], (rgb[h : 2 * h, :w] if self.stacked else None)
        except av.FFmpegError as e:
            raise InputError(f"{self.video} is damaged ({short_reason(e)})") from None

    def frames(self) -> Iterator[Frame]:
        (mx, my), _ = self.rig.maps
        for i, t, left, _ in self._eyes():
            yield Frame(i, t, cv2.remap(left, mx, my, cv2.INTER_LINEAR))

    def right_view(self) -> RightViews:
        return RightViews(self)

    def stereo_pairs(self) -> StereoPairs | None:
        """The right eye with the rig's baseline; None when the frames hold the left eye only."""
        if not self.stacked:
            return None
        return StereoPairs(
            right=self.right_view(),
            baseline_mm=self.rig.baseline_mm(),
            source=str(self.calibration),
            identity=digest_path(self.video),
        )

    def frame_count(self) -> int | None:
        try:
            with av.open(str(self.video)) as container:
                return int(container.streams.video[0].frames or 0) or None
        except (av.FFmpegError, OSError):
            return None

    def digest(self) -> str:
        parts = [self.kind, digest_path(self.video), digest_path(self.calibration)]
        if self.known_poses is not None:
            parts.append(digest_text(repr([p.round(9).tolist() for p in self.known_poses])))
        return digest_text("|".join([*parts, *self.given_digests()]))


class RightViews:
    """The rectified right eye by source_index, decoding forward and starting again only when
    an earlier frame is asked for (a matcher walks the frames in order)."""

    def __init__(self, source: StackedVideo) -> None:
        self.source = source
        self._it: Iterator | None = None
        self._at = -1

    def __call__(self, source_index: int) -> np.ndarray | None:
        if self._it is None or source_index <= self._at:
            self._it, self._at = self.source._eyes(), -1
        for i, _, _, right in self._it:
            self._at = i
            if i == source_index:
                (mx, my) = self.source.rig.maps[1]
                return None if right is None else cv2.remap(right, mx, my, cv2.INTER_LINEAR)
        self._it = None
        return None
