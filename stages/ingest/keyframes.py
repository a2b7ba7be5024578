"""Keyframes by content: in a long recording a frame is kept when the view has moved enough
since the last kept one, and dropped when it has nothing to reconstruct (washed out, blurred)
or when the camera stands still. Decided frame by frame as the video streams past, so a
recording of any length needs the memory of a few small grey frames, not of all its frames.

Motion is the median displacement of corners tracked with pyramidal Lucas-Kanade from the last
keyframe, frame to frame (OpenCV), on small grey copies; a fraction of the image diagonal, so
that one threshold fits every resolution. Blur is judged against the running median sharpness
of the recent frames (the sequence's median is not known while it streams).
"""

from __future__ import annotations

from collections import deque

import cv2
import numpy as np

from endopipe.stages.ingest.config import KeyframeConfig
from endopipe.stages.ingest.frame_quality import sharpness

#: Why a frame of a recording is not a keyframe (ingest's summary counts each).
KEYFRAME_REASONS = ("washed_out", "blurred", "still", "little_motion")


class KeyframeSelector:
    """Judges the frames of a recording one by one (`judge`): None keeps the frame."""

    def __init__(self, cfg: KeyframeConfig, blur_rel_threshold: float) -> None:
        self.cfg, self.blur_rel = cfg, blur_rel_threshold
        self._sharp: deque[float] = deque(maxlen=cfg.blur_window)
        self._prev: np.ndarray | None = None  # grey copy of the last frame tracked
        self._key_pts: np.ndarray | None = None  # the keyframe's corners (N, 1, 2)
        self._pts: np.ndarray | None = None  # where they are in the last frame tracked
        self._found = 0  # corners found on the keyframe
        self._diag = 1.0

    def judge(self, rgb: np.ndarray) -> str | None:
        """Why this frame is not a keyframe (one of KEYFRAME_REASONS), or None to keep it."""
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        if float((grey >= 250).mean()) > self.cfg.washed_out:
            return "washed_out"
        score = sharpness(grey)
        blurred = len(self._sharp) >= 3 and score < self.blur_rel * float(np.median(self._sharp))
        self._sharp.append(score)
        if blurred:
            return "blurred"
        small = self._small(grey)
        if self._prev is None:
            return self._keep(small)
        pts, ok = track_corners(self._prev, small, self._pts)
        if ok.sum() < max(8.0, self.cfg.min_tracked * self._found):
            return self._keep(small)  # the view changed past tracking (or has no corners)
        step = np.median(np.linalg.norm(pts[ok] - self._pts[ok], axis=-1)) / self._diag
        moved = np.median(np.linalg.norm(pts[ok] - self._key_pts[ok], axis=-1)) / self._diag
        self._prev, self._pts, self._key_pts = small, pts[ok], self._key_pts[ok]
        if moved >= self.cfg.min_flow:
            return self._keep(small)
        return "still" if step < self.cfg.still_flow else "little_motion"

    def _small(self, grey: np.ndarray) -> np.ndarray:
        h, w = grey.shape
        scale = min(1.0, self.cfg.track_size / max(h, w))
        size = (max(8, round(w * scale)), max(8, round(h * scale)))
        self._diag = float(np.hypot(*size))
        return cv2.resize(grey, size, interpolation=cv2.INTER_AREA)

    def _keep(self, small: np.ndarray) -> None:
        """This frame is the new keyframe: its corners are tracked from here."""
        corners = cv2.goodFeaturesToTrack(small, self.cfg.corners, 0.01, 5)
        found = np.zeros((0, 1, 2)) if corners is None else corners.reshape(-1, 1, 2)
        self._prev, self._key_pts = small, found.astype(np.float32)
        self._pts, self._found = self._key_pts.copy(), len(found)


def track_corners(
    a: np.ndarray, b: np.ndarray, pts: np.ndarray, max_error_px: float = 0.5
) -> tuple[np.ndarray, np.ndarray]:
    """Corners `pts` (N, 1, 2) float32 of grey `a` found in grey `b` by pyramidal Lucas-Kanade,
    and which were found both ways (forward-backward error under `max_error_px`)."""
    if len(pts) == 0:
        return pts, np.zeros(0, bool)
    fwd, st1, _ = cv2.calcOpticalFlowPyrLK(a, b, pts, None, winSize=(15, 15), maxLevel=3)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(b, a, fwd, None, winSize=(15, 15), maxLevel=3)
    err = np.linalg.norm((back - pts).reshape(-1, 2), axis=-1)
    ok = (st1.reshape(-1) == 1) & (st2.reshape(-1) == 1) & (err < max_error_px)
    return fwd, ok


def keyframes_on(cfg: KeyframeConfig, input_frames: int | None) -> bool:
    """Whether this input is a recording whose frames are kept by content."""
    if cfg.mode != "auto":
        return cfg.mode == "content"
    return input_frames is not None and input_frames > cfg.auto_above
