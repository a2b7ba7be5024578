"""The joined path's scale drift, measured from the scope's light, and the path redrawn without it.

Why: monocular SfM fixes no scale, and each window's reconstruction draws the end of its path
slightly smaller or larger than its start (0.2-2.4% a window on a synthetic withdrawal). The
windows join continuously, so that drift adds up along a recording (15% over two minutes) and
bends the one mesh, although every window alone is right.

The light sits at the camera and a wall's brightness falls with a power of its distance (the
near-light model the field already uses). With a fixed exposure and a wall whose albedo does not
change on average along the recording, a frame whose depths are drawn `s` times too large looks
`s^b` times too bright for them: from each keyframe's image and depth map comes a log-scale, its
falloff `b` from the pixels within each frame (no assumed gamma). Smoothed along the path it is
the drift; the camera path's steps and every depth map are divided by it. A scope whose exposure
follows the scene (auto-exposure) breaks the assumption: `--no-light-scale` leaves the path as
joined. So does a falloff too flat to measure, and a light that asks for more scale change
inside one window than SfM drifts (an exposure that changed); the summary says which.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel
from scipy.ndimage import gaussian_filter1d, median_filter

from endopipe.pipeline.runner import Pipeline
from endopipe.recording.join import Joined, ScaleKnot
from endopipe.recording.summary import LightScale

#: Pixels this dark are the ambient term's, this bright clip or are highlights: neither follows
#: the falloff.
DARKEST, BRIGHTEST = 0.05, 0.9
#: Pixels a frame contributes (a random subset of its usable ones).
SAMPLES_PER_FRAME = 4000
MIN_SAMPLES = 500
#: A falloff flatter than this (log brightness per log depth) measures nothing.
MIN_FALLOFF = 0.2
#: The drift is smoothed over this many keyframes (Gaussian sigma) after a median over
#: `OUTLIER_SPAN`: single frames scatter with their view (a fold, a dark cleft), the drift does
#: not.
SMOOTH_SIGMA = 25.0
OUTLIER_SPAN = 11
#: SfM drifts 2-6% in scale across a window (synthetic withdrawals, 14 windows); a light that asks
#: for more than this inside one window has seen the exposure change, not the scale.
MAX_WINDOW_DRIFT = 1.15


class FrameLight(BaseModel):
    """One keyframe's pixels for the falloff: log depth and log brightness, subsampled."""

    source_index: int
    log_depth: list[float]
    log_grey: list[float]


def frame_light(
    source_index: int, rgb: np.ndarray, depth: np.ndarray, rng: np.random.Generator
) -> FrameLight | None:
    """The usable pixels of one keyframe (None: too few)."""
    grey = (rgb.astype(np.float32) / 255.0) @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    ok = (depth > 0) & np.isfinite(depth) & (grey > DARKEST) & (grey < BRIGHTEST)
    idx = np.flatnonzero(ok)
    if len(idx) < MIN_SAMPLES:
        return None
    if len(idx) > SAMPLES_PER_FRAME:
        idx = rng.choice(idx, SAMPLES_PER_FRAME, replace=False)
    return FrameLight(
        source_index=source_index,
        log_depth=np.log(depth.reshape(-1)[idx]).tolist(),
        log_grey=np.log(grey.reshape(-1)[idx]).tolist(),
    )


def falloff(frames: Iterable[FrameLight]) -> float:
    """The pooled within-frame slope of log brightness on log depth, sign flipped (2/gamma for
    an inverse-square light seen through a gamma; lower where ambient light and the wall's
    tilt flatten it)."""
    xx = xy = 0.0
    for f in frames:
        x, y = np.asarray(f.log_depth), np.asarray(f.log_grey)
        x, y = x - x.mean(), y - y.mean()
        xx += float(x @ x)
        xy += float(x @ y)
    return -xy / xx if xx > 0 else 0.0


def log_scales(frames: list[FrameLight], b: float) -> np.ndarray:
    """Each frame's log of (its drawn depth / the recording's typical), up to a constant."""
    a = np.array([np.median(np.asarray(f.log_grey) + b * np.asarray(f.log_depth)) for f in frames])
    return (a - a.mean()) / b


def smooth_drift(log_scale: np.ndarray) -> np.ndarray:
    """The drift along the path: outliers off by a running median, then a wide Gaussian."""
    span = min(OUTLIER_SPAN, len(log_scale) | 1)
    robust = median_filter(log_scale, size=span, mode="nearest")
    return gaussian_filter1d(robust, SMOOTH_SIGMA, mode="nearest")


def measure(frames: list[FrameLight]) -> tuple[LightScale, np.ndarray | None]:
    """The verdict and, when it can be applied, the smoothed log-scale of each frame (in the
    order given, which is the path's), shifted to mean zero."""
    if len(frames) < 2 * OUTLIER_SPAN:
        return LightScale(applied=False, reason="too few keyframes to follow a drift"), None
    b = falloff(frames)
    if b < MIN_FALLOFF:
        return (
            LightScale(
                applied=False,
                reason=f"brightness hardly falls with depth (falloff {b:.2f}): no scale from it",
                falloff=b,
                frames=len(frames),
            ),
            None,
        )
    drift = smooth_drift(log_scales(frames, b))
    drift -= drift.mean()
    verdict = LightScale(
        applied=True, falloff=b, frames=len(frames), drift_range=float(np.exp(np.ptp(drift)))
    )
    return verdict, drift


def largest_window_drift(drift: np.ndarray, windows: list[str]) -> tuple[str, float]:
    """The window (each frame's, in path order) inside which the drift spans the most, and how
    much (largest over smallest scale)."""
    spans = {
        name: float(np.exp(np.ptp(drift[[w == name for w in windows]]))) for name in set(windows)
    }
    name = max(spans, key=spans.__getitem__)
    return name, spans[name]


def redraw_centres(centres: np.ndarray, drift: np.ndarray) -> np.ndarray:
    """Camera centres along a path (in its order) with each step divided by the drift there
    (the mean of its two ends'); the first centre stays where it is."""
    steps = np.diff(centres, axis=0)
    factor = np.exp(-0.5 * (drift[1:] + drift[:-1]))
    out = np.empty_like(centres)
    out[0] = centres[0]
    out[1:] = centres[0] + np.cumsum(steps * factor[:, None], axis=0)
    return out


def keyframe_lights(
    pipe: Pipeline, windows_dir: Path, joined: Joined, ingest: Any, segment: int, min_opacity: float
) -> list[FrameLight]:
    """The segment's keyframes' pixels, in path order: each keyframe's image (the recording's
    ingest) and its depth map from the window that placed it, in the segment's units."""
    from endopipe.stages.mesh.inputs import valid_depth

    image_of = {f.source_index: f.index for f in ingest.frames}
    views: dict[str, tuple[Any, dict[int, int]]] = {}
    rng = np.random.default_rng(0)
    out = []
    for f in sorted(
        (f for f in joined.frames if f.segment == segment), key=lambda f: f.source_index
    ):
        if f.window not in views:
            window = windows_dir / f.window
            index = {g.source_index: g.index for g in pipe.view(window, "ingest").frames}
            views[f.window] = (pipe.view(window, "depth"), index)
        depth, index = views[f.window]
        i = index.get(f.source_index)
        if i is None or not depth.has_depth(i) or f.source_index not in image_of:
            continue
        d = valid_depth(depth, i, min_opacity) * np.float32(
            joined.depth_scale(f.window, f.source_index)
        )
        found = frame_light(f.source_index, ingest.image(image_of[f.source_index]), d, rng)
        if found is not None:
            out.append(found)
    return out


def correct_drift(
    pipe: Pipeline, windows_dir: Path, joined: Joined, ingest: Any, min_opacity: float
) -> tuple[Joined, LightScale]:
    """The joined trajectory with its first segment's path redrawn for the drift the light
    measures (as joined when it cannot be measured), and the verdict. One window has no
    junction to carry a drift: it is left as it is."""
    if len([w for w, seg in joined.segment_of.items() if seg == 0]) < 2:
        return joined, LightScale(applied=False, reason="one window: no drift carried on")
    lights = keyframe_lights(pipe, windows_dir, joined, ingest, 0, min_opacity)
    verdict, drift = measure(lights)
    if drift is None:
        return joined, verdict
    by_index = {f.source_index: f for f in joined.frames if f.segment == 0}
    frames = [by_index[light.source_index] for light in lights]
    window, span = largest_window_drift(drift, [f.window for f in frames])
    verdict.window_drift = span
    if span > MAX_WINDOW_DRIFT:
        verdict.applied = False
        verdict.reason = (
            f"the light asks for a {span:.2f}x scale change inside {window}, more than a window's "
            f"SfM drifts ({MAX_WINDOW_DRIFT:.2f}x): the exposure changed, most likely"
        )
        return joined, verdict
    centres = np.array([np.array(f.c2w)[:3, 3] for f in frames])
    redrawn = redraw_centres(centres, drift)
    knots = [
        ScaleKnot(
            source_index=f.source_index,
            segment=0,
            factor=float(np.exp(-d)),
            centre=c.tolist(),
            redrawn=r.tolist(),
        )
        for f, d, c, r in zip(frames, drift, centres, redrawn, strict=True)
    ]
    out = joined.model_copy(update={"knots": knots})
    placed = []
    for f in joined.frames:
        if f.segment != 0:
            placed.append(f)
            continue
        redrawn_pose = out.redraw(0, f.source_index, np.array(f.c2w))
        placed.append(f.model_copy(update={"c2w": redrawn_pose.tolist()}))
    out.frames = placed
    return out, verdict
