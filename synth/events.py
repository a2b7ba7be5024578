"""What goes wrong in a real recording, put into a synthetic one with its truth: the camera
standing still (pauses), frames smeared by motion blur and frames washed out by the light.

The geometry of a spoiled frame stays exact (its depth and pose are the truth); only its image
is spoiled, so a reader can count how many of them ingest catches, by kind.
"""

from __future__ import annotations

import cv2
import numpy as np
from pydantic import BaseModel, Field

EDGE = 5  # frames at either end kept clean (a recording starts and ends on a usable view)


class Events(BaseModel):
    """Frame numbers of each event, written to gt/synth.json as `events`."""

    paused: list[int] = Field(default_factory=list, description="Frames at the previous pose.")
    blurred: list[int] = Field(default_factory=list, description="Frames with motion blur.")
    washed_out: list[int] = Field(default_factory=list, description="Frames flooded by light.")

    def still_mask(self, frames: int) -> np.ndarray:
        mask = np.zeros(frames, bool)
        mask[self.paused] = True
        return mask

    def kind_of(self, frame: int) -> str | None:
        """How frame `frame`'s image is spoiled, or None."""
        if frame in self.blurred:
            return "blurred"
        if frame in self.washed_out:
            return "washed_out"
        return None


def plan_events(
    frames: int,
    pauses: int,
    pause_frames: int,
    blurred: float,
    washed_out: float,
    rng: np.random.Generator,
) -> Events:
    """`pauses` stops of `pause_frames` frames each, spread over the recording; a `blurred`
    and a `washed_out` fraction of the frames, drawn at random (never the same frame twice)."""
    inner = np.arange(EDGE, max(EDGE, frames - EDGE))
    paused: list[int] = []
    if pauses and len(inner):
        starts = np.linspace(inner[0], inner[-1], pauses + 2)[1:-1].round().astype(int)
        for s in starts:
            paused += range(s + 1, min(s + 1 + pause_frames, frames - EDGE))
    free = np.setdiff1d(inner, paused)
    n_blur, n_wash = int(round(blurred * frames)), int(round(washed_out * frames))
    picks = rng.permutation(free)[: n_blur + n_wash]
    return Events(
        paused=sorted(int(i) for i in set(paused)),
        blurred=sorted(int(i) for i in picks[:n_blur]),
        washed_out=sorted(int(i) for i in picks[n_blur:]),
    )


def spoil(rgb: np.ndarray, kind: str | None, rng: np.random.Generator) -> np.ndarray:
    """The frame as the scope delivered it: smeared along a random direction over 4-6% of the
    image width (a fast move), or washed out (the light too close: 2.5-3.5x the exposure,
    clipped), or as it is."""
    if kind is None:
        return rgb
    if kind == "blurred":
        length = max(3, int(round(rng.uniform(0.04, 0.06) * rgb.shape[1])))
        kernel = np.zeros((length, length), np.float32)
        kernel[length // 2] = 1.0 / length
        centre = ((length - 1) / 2.0, (length - 1) / 2.0)
        turn = cv2.getRotationMatrix2D(centre, float(rng.uniform(0, 180)), 1.0)
        kernel = cv2.warpAffine(kernel, turn, (length, length))
        kernel /= kernel.sum()
        return cv2.filter2D(rgb, -1, kernel, borderType=cv2.BORDER_REFLECT)
    gain = rng.uniform(2.5, 3.5)
    return np.clip(rgb.astype(np.float32) * gain + 40.0, 0, 255).astype(np.uint8)
