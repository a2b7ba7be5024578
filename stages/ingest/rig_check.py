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

A rig whose calibration is a little off in rotation (a real SCARED keyframe's, 1.8 degrees: the
matched features then lie many pixels off their rows, more towards the edges) is not mended by a
shift. When the vertical disparity of the matches exceeds `MEND_PX` after the shift, the right
eye's rotation relative to the left is re-estimated from the matches (the rotation alone, fitted
to put them on their rows: an essential matrix would trade it for the baseline's direction) and
the right image is turned by it before matching; the baseline stays the calibration's (its
length fixes the scale). Taken only when it brings the vertical disparity down to under half,
said with the before and after; when nothing does, the rig's depth is left out with the
reason, never matched wrong.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
from pydantic import BaseModel, Field

from endopipe.stages.camera import Camera

#: SIFT's contrast threshold (OpenCV's default 0.04 finds a handful of features on smooth
#: tissue; a lower one finds them where the wall is faint, and the ratio test keeps them honest).
CONTRAST = 0.01
#: Fewest matched features for a frame's vertical disparity to count.
MIN_MATCHES = 20
#: Fewest frames with a measure for the check to judge the pairing; fewer frames (a pair
#: alone) have their rows checked, paired as named.
MIN_FRAMES = 6
#: Vertical disparity (median |row difference| of the matches, px at the working size) above
#: which the right eye's rotation is re-estimated.
MEND_PX = 1.0
#: A toe-in is fitted only when it lowers the rows' median error by more than this share
#: (measured on one synthetic pair with none: 0.19 degrees of it fitted to noise, 0.42 px ->
#: 0.41 px; a 2-degree turn over 8 frames, 0.6 degrees of it real: far more).
TOE_IN_GAIN = 1.0 / 0.85


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
    right_rotation: list[list[float]] | None = Field(
        None,
        description="the right eye's rotation relative to the left, re-estimated from the "
        "matches (3x3, right-from-left): the right image is turned by it before matching "
        "(the row shift then 0); None: the calibration's rows are kept",
    )
    vertical_px: float | None = Field(
        None, description="median |vertical disparity| of the matches as the rig came (px)"
    )
    vertical_mended_px: float | None = Field(
        None, description="... after the row shift or the rotation the check took (px)"
    )
    refused: str | None = Field(
        None,
        description="why the rig's depth is left out (its rows cannot be mended); None: used",
    )
    said: str = Field("", description="the finding in one line")

    def at_width(self, width: int, measured_width: int) -> RigCheck:
        """The check measured on images `measured_width` wide, its pixels brought to images
        `width` wide (the rotation holds at any size); the line says where it was measured."""
        f = width / measured_width

        def px(v: float | None) -> float | None:
            return None if v is None else round(v * f, 3)

        return self.model_copy(
            update={
                "row_shift_px": px(self.row_shift_px),
                "spread_as_named_px": px(self.spread_as_named_px),
                "spread_px": px(self.spread_px),
                "vertical_px": px(self.vertical_px),
                "vertical_mended_px": px(self.vertical_mended_px),
                "said": f"{self.said} (px of the {measured_width} px wide source images)",
            }
        )


def matched_points(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Features matched between two grey images of one rig (SIFT, Lowe's ratio test): (n, 2)
    pixel positions in each, kept where they are plausible for a rectified pair: within 8% of
    the height of one row, the right point not right of the left."""
    none = (np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32))
    sift = cv2.SIFT_create(1500, contrastThreshold=CONTRAST)
    ka, da = sift.detectAndCompute(left, None)
    kb, db = sift.detectAndCompute(right, None)
    if da is None or db is None or len(ka) < 2 or len(kb) < 2:
        return none
    pairs = cv2.BFMatcher().knnMatch(da, db, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < 0.7 * p[1].distance]
    if not good:
        return none
    a = np.float32([ka[m.queryIdx].pt for m in good])
    b = np.float32([kb[m.trainIdx].pt for m in good])
    dy, dx = a[:, 1] - b[:, 1], a[:, 0] - b[:, 0]
    keep = (np.abs(dy) < 0.08 * left.shape[0]) & (dx > -2.0) & (dx < 0.5 * left.shape[1])
    return a[keep], b[keep]


def row_disparities(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Vertical disparities (left row minus right row, px) of the features matched between two
    grey images of one rig (`matched_points`)."""
    a, b = matched_points(left, right)
    return a[:, 1] - b[:, 1]


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
    camera: Camera | None = None,
    px: float = 1.0,
) -> RigCheck:
    """Check the pairing and the rows of a rig on `frames` of the kept frames' `sources`
    (source indices); `left(s)` / `right(s)` give the two eyes' RGB images at the working size
    (right: None where it has none). A pairing other than as named is taken when its spread is
    at least `min_gain` times smaller and the named one's exceeds `min_spread_px`; the row shift
    when the chosen pairing's median vertical disparity exceeds `min_row_px`; with the
    rectified `camera` (working size), the right eye's rotation when a shift leaves the matches
    more than MEND_PX off their rows. The thresholds are in pixels of the working size: `px`
    of the images given make one (a pair alone is checked at its own, larger size)."""
    picked = [sources[int(round(k))] for k in np.linspace(0, len(sources) - 1, frames)]
    picked = sorted(set(picked))
    fewest = min(MIN_FRAMES, len(picked))  # a pair alone is checked for its rows only
    if len(picked) < MIN_FRAMES:
        max_offset = 0  # too few frames to tell one pairing's spread from another's
    lefts = {s: _grey(left(s)) for s in picked}
    points: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}  # matches per frame, by offset
    for off in range(-max_offset, max_offset + 1):
        pts = []
        for s in picked:
            r = right(s + off)
            if r is None:
                continue
            a, b = matched_points(lefts[s], _grey(r))
            if len(a) >= MIN_MATCHES:
                pts.append((a, b))
        if len(pts) >= fewest:
            points[off] = pts
    # each frame's median vertical disparity, by offset
    by_offset = {
        off: [float(np.median(a[:, 1] - b[:, 1])) for a, b in pts] for off, pts in points.items()
    }
    if 0 not in by_offset:
        return RigCheck(
            frames=len(by_offset.get(0, [])),
            said="stereo rig not checked: too few features matched between the eyes",
        )
    spread = {off: float(np.std(rows)) for off, rows in by_offset.items()}
    best = min(spread, key=spread.get)  # type: ignore[arg-type]
    named = spread[0]
    mend_px, min_spread_px, min_row_px = MEND_PX * px, min_spread_px * px, min_row_px * px
    offset = best if named > min_spread_px and named >= min_gain * spread[best] else 0
    rows = by_offset[offset]
    row = float(np.median(rows))
    shift = row if abs(row) > min_row_px else 0.0
    a = np.concatenate([p[0] for p in points[offset]])
    b = np.concatenate([p[1] for p in points[offset]])
    as_came = float(np.median(np.abs(a[:, 1] - b[:, 1])))
    after_shift = float(np.median(np.abs(a[:, 1] - b[:, 1] - shift)))
    turn, refused = None, None
    if camera is not None and as_came > mend_px:
        # a rotation explains a shift too (about the rows' axis), and what a shift cannot: a
        # toe-in shows only as rows parting towards the corners, and biases every disparity
        turn = right_rotation(a, b, camera)
        if turn is not None:
            turned = float(np.median(np.abs(a[:, 1] - turned_points(b, turn, camera)[:, 1])))
            turn = turn if turned < 0.5 * as_came and turned <= after_shift else None
    mended = turned if turn is not None else after_shift
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
    if turn is not None:
        shift = 0.0
        parts.append(
            f"matched features lie {as_came:.2f} px off their rows (median): the right "
            f"eye's rotation re-estimated from {len(a)} matches ({rotation_deg(turn):.2f} deg "
            f"from the calibration's), the right image turned by it: {mended:.2f} px"
        )
    elif camera is not None and after_shift > mend_px:
        refused = (
            f"matched features lie {after_shift:.2f} px off their rows (median) and no rotation "
            "of the right eye brings them onto them: the rig's depth is left out (check the "
            "rectification; ingest.stereo.check=false matches it as it is)"
        )
        parts.append(refused)
    elif shift:
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
        right_rotation=turn.tolist() if turn is not None else None,
        vertical_px=round(as_came, 3),
        vertical_mended_px=round(mended, 3),
        refused=refused,
        said="stereo rig checked against its images: " + "; ".join(parts),
    )


def right_rotation(a: np.ndarray, b: np.ndarray, camera: Camera) -> np.ndarray | None:
    """The right eye's rotation relative to the left (right-from-left, 3x3) from matched points
    `a` (left) and `b` (right) of a pinhole `camera` (both eyes rectified to it): the rotation
    that puts the turned right points on the left points' rows (robust least squares, 1 px
    scale). The baseline stays along the rows: a rectified rig's, so that its direction cannot
    soak up the rotation (an essential matrix on a 5 mm baseline trades one for the other: 1.3
    degrees off on a synthetic rig turned by 2). None with too few matches."""
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    if len(a) < 2 * MIN_MATCHES:
        return None

    def rows_apart(v: np.ndarray) -> np.ndarray:
        r = Rotation.from_rotvec(v).as_matrix()
        return a[:, 1] - turned_points(b, r, camera)[:, 1]

    def fitted(free: list[int]) -> tuple[np.ndarray, float] | None:
        def apart(x: np.ndarray) -> np.ndarray:
            v = np.zeros(3)
            v[free] = x
            return rows_apart(v)

        fit = least_squares(apart, np.zeros(len(free)), loss="soft_l1", f_scale=1.0)
        if not fit.success:
            return None
        v = np.zeros(3)
        v[free] = fit.x
        return v, float(np.median(np.abs(rows_apart(v))))

    # A toe-in (the turn about the columns' axis) parts the rows only towards the corners (by
    # x y / f of its angle): on a few hundred matches it fits their noise. It is kept only when
    # it clearly lowers the rows' error; a tilt and a roll move rows everywhere.
    tilt_roll, full = fitted([0, 2]), fitted([0, 1, 2])
    best = min(
        (f for f in (tilt_roll, full) if f is not None),
        key=lambda f: f[1] * (TOE_IN_GAIN if f is full else 1.0),
        default=None,
    )
    return None if best is None else Rotation.from_rotvec(best[0]).as_matrix()


def rotation_deg(rotation: np.ndarray) -> float:
    """The angle of a rotation matrix, degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0))))


def turned_points(b: np.ndarray, rotation: np.ndarray, camera: Camera) -> np.ndarray:
    """Right-image points where the right image turned by `rotation` (its camera brought parallel
    to the left's) shows them."""
    k = np.asarray(camera.matrix(), np.float64)
    h = k @ rotation.T @ np.linalg.inv(k)
    return cv2.perspectiveTransform(b.reshape(-1, 1, 2).astype(np.float64), h).reshape(-1, 2)


def mended_right(image: np.ndarray, rig: RigCheck, camera: Camera | None) -> np.ndarray:
    """The right image as the check found it should be matched: turned by the re-estimated
    rotation, or shifted by the row offset, or as it is."""
    if rig.right_rotation is None or camera is None:
        return shifted_rows(image, rig.row_shift_px)
    k = np.asarray(camera.matrix(), np.float64)
    h = k @ np.asarray(rig.right_rotation).T @ np.linalg.inv(k)
    size = (image.shape[1], image.shape[0])
    return cv2.warpPerspective(image, h, size, flags=cv2.INTER_LINEAR, borderValue=0)


def shifted_rows(image: np.ndarray, shift_px: float) -> np.ndarray:
    """`image` moved down by `shift_px` rows (sub-pixel, bilinear; the uncovered rows black)."""
    if not shift_px:
        return image
    h, w = image.shape[:2]
    m = np.float32([[1, 0, 0], [0, 1, shift_px]])
    return cv2.warpAffine(image, m, (w, h), flags=cv2.INTER_LINEAR, borderValue=0)
