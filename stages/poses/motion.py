"""What the footage is, judged before SfM: does the camera move, and does the scene hold still?

Why: COLMAP registers a still camera over moving tissue on the tissue's own motion and calls
the made-up path sound (a da Vinci clip with the camera fixed: a 23.6-unit path, verdict ok).
Corners tracked over a second tell the two apart without any geometry, by the motion's
structure rather than its amount: a moving camera moves (nearly) every corner, and with one
coherent motion of the whole view; a still camera leaves a good part of the view where it was,
and the tissue that moves (pulled, breathing, cut) does not follow one motion with the rest.
How far the corners went does not tell: tissue pulled hard in part of a fixed camera's view
moved them 2.59% of the diagonal in a second, more than a slow scope's.

Per span: the share of the tracked corners that stayed put (ended within `still_corner` of
where they started) and the share one homography fitted with RANSAC explains at the same
tolerance (at least as many: standing still is a homography too). The camera stands still when
enough corners stayed put and standing still explains most of what the best global motion does
(a zooming camera leaves the corners near its centre put, but one homography explains all).
Measured on real clips at the ingest's 320-px working size, medians over the spans, tolerance
0.8% of the diagonal (share stayed put / standing still over the homography's share): the fixed
da Vinci camera 0.54 / 0.86 (its corners moved 0.73% of the diagonal in a second); moving
scopes 0-0.073 / 0-0.17 (the C3VD colonoscope the most: 3.5% in a second, 30% of the corners
kept), a Hamlyn laparoscope 0.01 / 0.01, a sinus scope's view changed in every span.
Thresholds: `MotionConfig` (config.py).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal, NamedTuple

import cv2
import numpy as np
from pydantic import BaseModel, Field

from endopipe.stages.poses.config import MotionConfig

#: Forward-backward tracking error (px) past which a corner is lost.
FB_MAX_PX = 0.5
#: Fewest corners a span must keep to its end for its motion to be measured.
MIN_TRACKED = 10


class FootageMotion(BaseModel):
    """The footage's motion, with its evidence (poses summary `motion`, verdict.json)."""

    camera: Literal["still", "moving"]
    scene: Literal["rigid", "moving", "not measured"]
    camera_move: float | None = Field(
        description="median corner travel over a span, / diagonal (evidence; the judgement "
        "rests on still_share and identity_part); None: too few corners lasted the spans to "
        "measure it (the view changed)"
    )
    kept: float = Field(description="median share of corners tracked to a span's end")
    still_share: float | None = Field(
        None,
        description="median share of the tracked corners that stayed put over a span (within "
        "poses.motion.still_corner of where they started); a span whose view changed counts 0",
    )
    homography_share: float | None = Field(
        None,
        description="median share of the tracked corners one homography (RANSAC) explains at "
        "the same tolerance: one global motion of the view",
    )
    identity_part: float | None = Field(
        None,
        description="median over the spans of still_share / homography_share: 1 when the best "
        "global motion is none (a still camera), near 0 when the whole view moved as one",
    )
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


class SpanMotion(NamedTuple):
    """One span's evidence: shares of its corners; distances / the image diagonal."""

    kept: float  # share of the span's corners tracked to its end
    travel: float  # the tracked corners' median travel, start to end; inf: the view changed
    still: float  # share of the tracked corners that ended within still_corner of their start
    coherent: float  # share within still_corner of the homography that explains most (>= still)
    strayed: float  # share that strayed over moving_corner on the way; nan: the view changed

    @property
    def identity_part(self) -> float:
        """How much of what one global motion explains standing still explains (0..1)."""
        return self.still / self.coherent if self.coherent > 0 else 0.0


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


def span_motion(
    start: np.ndarray,
    last: np.ndarray,
    stray: np.ndarray,
    alive: np.ndarray,
    diag: float,
    cfg: MotionConfig,
) -> SpanMotion:
    """One span's evidence from its corners (`track_span`'s output, pixels; `diag` the image
    diagonal in pixels). A span that kept under MIN_TRACKED corners or under `cfg.min_kept` of
    them saw the view change: nothing in it stayed put."""
    n, k = len(start), int(alive.sum())
    kept = k / n if n else 0.0
    if k < max(MIN_TRACKED, cfg.min_kept * n):
        return SpanMotion(kept, np.inf, 0.0, 0.0, np.nan)
    a = start[alive].astype(np.float64)
    b = last[alive].astype(np.float64)
    tol = cfg.still_corner * diag
    moved = np.linalg.norm(b - a, axis=1)
    still = float(np.mean(moved < tol))
    h, inliers = cv2.findHomography(a, b, cv2.RANSAC, tol)
    coherent = float(inliers.mean()) if h is not None and inliers is not None else 0.0
    return SpanMotion(
        kept=kept,
        travel=float(np.median(moved)) / diag,
        still=still,
        coherent=max(coherent, still),  # standing still is one homography too
        strayed=float(np.mean(stray[alive] / diag > cfg.moving_corner)),
    )


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
    spans = []
    for s in starts:
        frames = [read(int(i)) for i in range(s, s + span + 1)]
        grey = [g for g, _ in frames]
        diag = float(np.hypot(*grey[0].shape[:2]))
        start, last, stray, alive = track_span(grey, frames[0][1], cfg.corners)
        if len(start):
            spans.append(span_motion(start, last, stray, alive, diag, cfg))
    return judge_spans(spans, span, span / fps, cfg)


def judge_spans(
    spans: list[SpanMotion], span_frames: int, seconds: float, cfg: MotionConfig
) -> FootageMotion:
    """The judgement over the spans' evidence (medians): the camera stands still when at least
    `cfg.still_share` of the corners stayed put and standing still explains at least
    `cfg.identity_part` of what one homography does; otherwise it moved."""
    if not spans:
        return FootageMotion(
            camera="moving",
            scene="not measured",
            camera_move=None,
            kept=0.0,
            span_frames=span_frames,
            spans=0,
            said="no corners to track: the camera is taken to move",
        )
    kept = float(np.median([s.kept for s in spans]))
    move = float(np.median([s.travel for s in spans]))
    still = float(np.median([s.still for s in spans]))
    coherent = float(np.median([s.coherent for s in spans]))
    part = float(np.median([s.identity_part for s in spans]))
    camera: Literal["still", "moving"] = (
        "still" if still >= cfg.still_share and part >= cfg.identity_part else "moving"
    )

    def bound(value: float, limit: float) -> str:
        return f"at least {100 * limit:g}%" if value >= limit else f"under {100 * limit:g}%"

    travel = (
        f"corners moved {100 * move:.2f}% of the diagonal"
        if np.isfinite(move)  # inf: most spans kept too few corners to their end
        else f"the view changed: too few corners lasted {seconds:.2g} s to measure their travel"
    )
    evidence = (
        f"{100 * still:.0f}% of the corners stayed within {100 * cfg.still_corner:g}% of the "
        f"image diagonal over {seconds:.2g} s ({bound(still, cfg.still_share)}); standing "
        f"still explains {100 * part:.0f}% of what one homography does ({100 * coherent:.0f}% "
        f"of the corners; {bound(part, cfg.identity_part)}); median of {len(spans)} "
        f"span{'s' if len(spans) > 1 else ''}, "
        f"{100 * kept:.0f}% tracked to the end; {travel}"
    )
    shared = {
        "camera_move": move if np.isfinite(move) else None,
        "kept": kept,
        "still_share": still,
        "homography_share": coherent,
        "identity_part": part,
        "span_frames": span_frames,
        "spans": len(spans),
    }
    if camera == "moving":
        return FootageMotion(
            camera="moving",
            scene="not measured",
            said=f"camera moving: {evidence}; the scene is taken as rigid",
            **shared,
        )
    strayed = [s.strayed for s in spans if np.isfinite(s.strayed)]
    share = float(np.median(strayed)) if strayed else 1.0  # none lasted: all moved or were lost
    scene: Literal["rigid", "moving"] = "moving" if share > cfg.deforming_share else "rigid"
    strays = (
        f"{100 * share:.0f}% of the corners strayed over {100 * cfg.moving_corner:g}% of the "
        "diagonal"
    )
    said = (
        f"camera still: {evidence}; "
        + ("tissue moving: " if scene == "moving" else "scene still: only ")
        + strays
    )
    return FootageMotion(camera="still", scene=scene, moving_share=share, said=said, **shared)


def footage_fps(times: list[float | None], default: float) -> float:
    """Frames per second from the frames' video times (their median step), else `default`."""
    t = np.array([x for x in times if x is not None], dtype=np.float64)
    steps = np.diff(t)
    steps = steps[steps > 0]
    return float(1.0 / np.median(steps)) if len(steps) else default
