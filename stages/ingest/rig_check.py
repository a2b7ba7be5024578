"""A stereo rig checked against its own images before its depth is trusted: are the two eyes'
frames of one moment, and do matched features lie on one row?

Why: a rectified pair puts a point on the same row in both eyes, and a moving camera moves it
between frames. When the right eye's frames lag the left's (two video streams captured apart,
a dropped or doubled frame), each pair mixes two moments: the camera's motion between them
adds to the disparity (a depth error that follows the camera's speed) and, when it moves up or
down, to the row too. Hamlyn's rectified01 as released pairs each left frame with the right
frame of the moment before: its stereo depth then swings 0.84-1.18x the SfM's along the clip
with the camera's sideways speed (correlation -0.98), and pairing each left frame with the
next right frame brings the swing under 0.1 px of disparity. The release's own depth maps were
made from the same mixed pairs.

Measured per frame: the median vertical disparity of features matched between the two eyes
(SIFT, ratio test). Paired at the right moment it is one number for the whole clip (the
rectification's own row offset); paired across moments it varies with the camera's vertical
speed. The pairing whose per-frame values spread least wins, if it clearly beats pairing as
named. A row offset left over is a rectification error: the right image is shifted by it before
matching (a fraction of a pixel already costs the matcher).
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
from pydantic import BaseModel, Field

#: Fewest matched features for a frame's vertical disparity to count.
MIN_MATCHES = 20
#: Fewest frames with a measure for the check to judge anything.
MIN_FRAMES = 6


class RigCheck(BaseModel):
    """What the check found (frames.json, the ingest summary) and what the matcher then did."""

    frame_offset: int = Field(
        0, description="each left frame s is matched with the right frame s + this"
    )
    row_shift_px: float = Field(
        0.0,
        description="the right image moved down by this many pixels (working size) before "
        "matching: the rectification's vertical disparity",
    )
    spread_as_named_px: float | None = Field(
        None, description="spread (std) over frames of the vertical disparity, paired as named"
    )
    spread_px: float | None = Field(None, description="... paired as chosen (frame_offset)")
    frames: int = Field(0, description="frames measured")
    said: str = Field("", description="the finding in one line")


def row_disparities(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Vertical disparities (left row minus right row, px) of features matched between two
    grey images of one rig (SIFT, Lowe's ratio test), kept where they are plausible for a
    rectified pair: within 8% of the height of one row, the right point not right of the left."""
    sift = cv2.SIFT_create(1500)
    ka, da = sift.detectAndCompute(left, None)
    kb, db = sift.detectAndCompute(right, None)
    if da is None or db is None or len(ka) < 2 or len(kb) < 2:
        return np.zeros(0)
    pairs = cv2.BFMatcher().knnMatch(da, db, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < 0.7 * p[1].distance]
    if not good:
        return np.zeros(0)
    a = np.float32([ka[m.queryIdx].pt for m in good])
    b = np.float32([kb[m.trainIdx].pt for m in good])
    dy, dx = a[:, 1] - b[:, 1], a[:, 0] - b[:, 0]
    keep = (np.abs(dy) < 0.08 * left.shape[0]) & (dx > -2.0) & (dx < 0.5 * left.shape[1])
    return dy[keep]


def _grey(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)


def check_rig(
    sources: list[int],
    left: Callable[[int], np.ndarray],
    right: Callable[[int], np.ndarray | None],
    max_offset: int = 2,
    frames: int = 16,
    min_gain: float = 2.0,
    min_spread_px: float = 0.1,
    min_row_px: float = 0.25,
) -> RigCheck:
    """Check the pairing and the rows of a rig on `frames` of the kept frames' `sources`
    (source indices); `left(s)` / `right(s)` give the two eyes' RGB images at the working size
    (right: None where it has none). A pairing other than as named is taken when its spread is
    at least `min_gain` times smaller and the named one's exceeds `min_spread_px`; the row shift
    when the chosen pairing's median vertical disparity exceeds `min_row_px`."""
    picked = [sources[int(round(k))] for k in np.linspace(0, len(sources) - 1, frames)]
    picked = sorted(set(picked))
    lefts = {s: _grey(left(s)) for s in picked}
    by_offset: dict[int, list[float]] = {}
    for off in range(-max_offset, max_offset + 1):
        rows = []
        for s in picked:
            r = right(s + off)
            if r is None:
                continue
            dy = row_disparities(lefts[s], _grey(r))
            if len(dy) >= MIN_MATCHES:
                rows.append(float(np.median(dy)))
        if len(rows) >= MIN_FRAMES:
            by_offset[off] = rows
    if 0 not in by_offset:
        return RigCheck(
            frames=len(by_offset.get(0, [])),
            said="stereo rig not checked: too few features matched between the eyes",
        )
    spread = {off: float(np.std(rows)) for off, rows in by_offset.items()}
    best = min(spread, key=spread.get)  # type: ignore[arg-type]
    named = spread[0]
    offset = best if named > min_spread_px and named >= min_gain * spread[best] else 0
    rows = by_offset[offset]
    row = float(np.median(rows))
    shift = row if abs(row) > min_row_px else 0.0
    parts = []
    if offset:
        which = "later" if offset > 0 else "earlier"
        parts.append(
            f"the eyes' frames are {abs(offset)} apart: features matched between them change "
            f"row by {named:.2f} px (std over {len(by_offset[0])} frames) paired as named, by "
            f"{spread[offset]:.2f} px with the right frame {abs(offset)} {which}, so each left "
            f"frame is matched with that one"
        )
    else:
        parts.append(
            f"the eyes' frames pair as named (row of matched features steady to {named:.2f} px "
            f"over {len(by_offset[0])} frames)"
        )
    if shift:
        parts.append(
            f"the rectification leaves a vertical disparity of {row:.2f} px: the right image "
            "is shifted by it before matching"
        )
    else:
        parts.append(f"rows agree to {abs(row):.2f} px")
    return RigCheck(
        frame_offset=offset,
        row_shift_px=round(shift, 3),
        spread_as_named_px=round(named, 3),
        spread_px=round(spread[offset], 3),
        frames=len(rows),
        said="stereo rig checked against its images: " + "; ".join(parts),
    )


def shifted_rows(image: np.ndarray, shift_px: float) -> np.ndarray:
    """`image` moved down by `shift_px` rows (sub-pixel, bilinear; the uncovered rows black)."""
    if not shift_px:
        return image
    h, w = image.shape[:2]
    m = np.float32([[1, 0, 0], [0, 1, shift_px]])
    return cv2.warpAffine(image, m, (w, h), flags=cv2.INTER_LINEAR, borderValue=0)
