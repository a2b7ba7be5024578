"""What the footage is, judged before SfM: does the camera move, and does the scene hold still?

Why: COLMAP registers a still camera over moving tissue on the tissue's own motion and calls
the made-up path sound (a da Vinci clip with the camera fixed: a 23.6-unit path, verdict ok).
Corners tracked frame to frame tell the two apart without any geometry: over a second a moving
camera carries nearly every corner far (or out of view), while a still one leaves the scene
where it was and only tissue or instruments move, by a few pixels and mostly back.

Measured on real clips at the ingest's 320-px working size (median over the spans, corners
moved in one second, fraction of the image diagonal): the fixed da Vinci camera 0.66%; the
moving laparoscope 5.6%, the C3VD colonoscope 2.9%, a plastic colon under a moving camera
8.5%. Thresholds: `MotionConfig` (config.py).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import cv2
import numpy as np
from pydantic import BaseModel, Field

from endopipe.stages.poses.config import MotionConfig

#: Forward-backward tracking error (px) past which a corner is lost.
FB_MAX_PX = 0.5


class FootageMotion(BaseModel):
    """The footage's motion, with its evidence (poses summary `motion`, verdict.json)."""

    camera: Literal["still", "moving"]
    scene: Literal["rigid", "moving", "not measured"]
    camera_move: float | None = Field(
        description="median corner travel over a span, / diagonal; None: too few corners "
        "lasted the spans to measure it (the view changed)"
    )
    kept: float = Field(description="median share of corners tracked to a span's end")
    moving_share: float | None = Field(
        None, description="still camera: share of corners that moved with the scene"
    )
    span_frames: int
    spans: int
    said: str = Field(description="the judgement and its evidence, in words")

    @property
    def label(self) -> str:
        """'camera still, tissue moving' and the like: the verdict's words."""
        scene = {
            "moving": "tissue moving",
            "rigid": "scene still",
            "not measured": "scene taken as rigid",
        }[self.scene]
        return f"camera {self.camera}, {scene}"


def track_span(grey: list[np.ndarray], mask: np.ndarray | None, corners: int):
    """Corners of the first image followed through the rest: (start (K, 2), last (K, 2), farthest
    stray (K,), alive (K,)) in pixels; a corner is lost once its forward-backward error exceeds
    FB_MAX_PX."""
    p0 = cv2.goodFeaturesToTrack(grey[0], corners, 0.001, 5, mask=mask)
    if p0 is None:
        empty = np.zeros((0, 2), np.float32)
        return empty, empty, np.zeros(0), np.zeros(0, bool)
    start = p0[:, 0].copy()
    pts = p0.copy()
    alive = np.ones(len(start), bool)
    stray = np.zeros(len(start))
    lk = {"winSize": (21, 21), "maxLevel": 3}
    for a, b in zip(grey[:-1], grey[1:], strict=True):
        nxt, st, _ = cv2.calcOpticalFlowPyrLK(a, b, pts, None, **lk)
        back, st2, _ = cv2.calcOpticalFlowPyrLK(b, a, nxt, None, **lk)
        fb = np.linalg.norm(back[:, 0] - pts[:, 0], axis=1)
        alive &= (st[:, 0] == 1) & (st2[:, 0] == 1) & (fb < FB_MAX_PX)
        pts = nxt
        stray = np.where(alive, np.maximum(stray, np.linalg.norm(pts[:, 0] - start, axis=1)), stray)
    return start, pts[:, 0], stray, alive


def judge_motion(
    n: int,
    read: Callable[[int], tuple[np.ndarray, np.ndarray | None]],
    fps: float,
    cfg: MotionConfig,
) -> FootageMotion:
    """Judge `n` consecutive frames at `fps`; `read(i)` gives frame i's grey uint8 image and its
    usable-pixel mask (255 = use). Only the frames of the sampled spans are read."""
    span = max(1, min(n - 1, round(cfg.span_s * fps)))
    starts = np.unique(np.linspace(0, n - 1 - span, min(cfg.spans, n - span)).round().astype(int))
    moves, kept, moving = [], [], []
    for s in starts:
        frames = [read(int(i)) for i in range(s, s + span + 1)]
        grey = [g for g, _ in frames]
        diag = float(np.hypot(*grey[0].shape[:2]))
        start, last, stray, alive = track_span(grey, frames[0][1], cfg.corners)
        if not len(start):
            continue
        kept.append(float(alive.mean()))
        if alive.sum() < 10:
            moves.append(np.inf)
            continue
        moves.append(float(np.median(np.linalg.norm(last[alive] - start[alive], axis=1))) / diag)
        moving.append(float(np.mean(stray[alive] / diag > cfg.moving_corner)))
    if not moves:
        return FootageMotion(
            camera="moving",
            scene="not measured",
            camera_move=None,
            kept=0.0,
            span_frames=span,
            spans=0,
            said="no corners to track: the camera is taken to move",
        )
    move, kept_share = float(np.median(moves)), float(np.median(kept))
    seconds = span / fps
    counted = f"median of {len(moves)} spans; {100 * kept_share:.0f}% tracked to the end"
    travel = (
        f"corners moved {100 * move:.2f}% of the image diagonal in {seconds:.2g} s ({counted})"
        if np.isfinite(move)  # inf: most spans kept under 10 corners to their end
        else f"too few corners lasted {seconds:.2g} s to measure their travel ({counted})"
    )
    if move >= cfg.still_move or kept_share < cfg.min_kept:
        why = (
            f"{travel}, over {100 * cfg.still_move:g}%"
            if np.isfinite(move) and move >= cfg.still_move
            else f"{travel}: the view changed"
        )
        return FootageMotion(
            camera="moving",
            scene="not measured",
            camera_move=move if np.isfinite(move) else None,
            kept=kept_share,
            span_frames=span,
            spans=len(moves),
            said=f"camera moving: {why}; the scene is taken as rigid",
        )
    share = float(np.median(moving))
    scene: Literal["rigid", "moving"] = "moving" if share > cfg.deforming_share else "rigid"
    strays = (
        f"{100 * share:.0f}% of the corners strayed over {100 * cfg.moving_corner:g}% of the "
        "diagonal"
    )
    said = (
        f"camera still: {travel}, under {100 * cfg.still_move:g}%; "
        + ("tissue moving: " if scene == "moving" else "scene still: only ")
        + strays
    )
    return FootageMotion(
        camera="still",
        scene=scene,
        camera_move=move,
        kept=kept_share,
        moving_share=share,
        span_frames=span,
        spans=len(moves),
        said=said,
    )


def footage_fps(times: list[float | None], default: float) -> float:
    """Frames per second from the frames' video times (their median step), else `default`."""
    t = np.array([x for x in times if x is not None], dtype=np.float64)
    steps = np.diff(t)
    steps = steps[steps > 0]
    return float(1.0 / np.median(steps)) if len(steps) else default
