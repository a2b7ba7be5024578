"""Which input frames ingest keeps: time window, stride, and blank / duplicate / blurred
frames dropped, each reason counted for the summary; in a long recording, keyframes by content
(keyframes.py) instead of every usable frame.

With `max_frames`, decoding stops as soon as enough frames are kept: a 60-frame run on a
250-frame video reads what it needs, and the rest is counted as "not_read". Kept frames are
held at the working resolution, not the source's.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.pipeline.stage import StageContext
from endopipe.stages.ingest.config import IngestConfig
from endopipe.stages.ingest.frame_quality import frame_difference, sharpness
from endopipe.stages.ingest.keyframes import KEYFRAME_REASONS, KeyframeSelector, keyframes_on
from endopipe.stages.io.input_source import Frame, InputSource

REASONS = (
    "outside_time_window",
    "not_in_window",
    "stride",
    "blank",
    "duplicate",
    "blurred",
    "max_frames",
)


@dataclass
class Selection:
    """The kept frames and where every other frame of the input went."""

    frames: list[Frame]  # at the working resolution
    dropped: dict[str, int]  # reason -> frames; "not_read" when decoding stopped early
    read: int  # frames decoded
    total: int | None  # frames in the input (None: unknown, decoding stopped early)
    source_size: tuple[int, int]  # (width, height) of the input's frames
    size: tuple[int, int]  # (width, height) the kept frames were brought to
    keyframes: bool = False  # kept by content (a recording)
    dropped_frames: dict[str, list[int]] | None = None  # by content: source_index by reason


def select_frames(
    source: InputSource, cfg: IngestConfig, ctx: StageContext, fewest: int | None = None
) -> Selection:
    """Stride, time window, blank / duplicate / blur filtering, or keyframes by content in a
    recording; reasons are counted. Fewer than `fewest` frames (default `min_frames`) is an
    error: a stereo input asks for one (its pair alone gives depth)."""
    declared = source.frame_count()
    by_content = keyframes_on(cfg.keyframes, declared)
    dropped = dict.fromkeys(REASONS + (KEYFRAME_REASONS if by_content else ()), 0)
    selector = KeyframeSelector(cfg.keyframes, cfg.blur_rel_threshold) if by_content else None
    candidates: list[Frame] = []
    scores: list[float] = []  # sharpness of each candidate (blur is judged against the median)
    read, finished = 0, True
    last_grey: np.ndarray | None = None
    source_size = size = (0, 0)
    timeline: dict[str, list[int]] = {}
    wanted = set(cfg.frames) if cfg.frames is not None else None
    last_wanted = max(wanted, default=-1) if wanted is not None else None
    with ctx.progress("keyframes" if by_content else "decode", total=declared) as advance:
        for frame in source.frames():
            read += 1
            advance()
            if read == 1:
                source_size = (frame.rgb.shape[1], frame.rgb.shape[0])
                size = working_size(*source_size, cfg.max_size)
            if last_wanted is not None and frame.source_index > last_wanted:
                read -= 1  # not this window's: left for "not_read"
                finished = False  # a window of a recording: its last frame is behind us
                break
            if wanted is not None and frame.source_index not in wanted:
                dropped["not_in_window"] += 1
                continue
            reason = _drop_reason(frame, read - 1, cfg, None if by_content else last_grey)
            if reason is None and selector is not None:
                reason = selector.judge(frame.rgb)
                if reason is not None:
                    timeline.setdefault(reason, []).append(frame.source_index)
            if reason is not None:
                dropped[reason] += 1
                continue
            last_grey = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
            scores.append(sharpness(frame.rgb) if cfg.drop_blurred and not by_content else 0.0)
            candidates.append(Frame(frame.source_index, frame.time_s, resize(frame.rgb, size)))
            if _enough(scores, cfg):
                finished = False
                break
    if read == 0:
        raise InputError(f"{source.path} holds no decodable frames; check the file")
    if not candidates:
        raise InputError(
            f"all {read} frames of {source.path} are blank (black) or outside the time window; "
            "check the video and --set ingest.start_s/end_s"
        )
    keep = _sharp_enough(scores, cfg)
    dropped["blurred"] += int((~keep).sum())
    candidates = [f for f, k in zip(candidates, keep, strict=True) if k]
    if cfg.max_frames is not None and len(candidates) > cfg.max_frames:
        dropped["max_frames"] = len(candidates) - cfg.max_frames
        candidates = candidates[: cfg.max_frames]
    total = read if finished else declared
    if total is not None:
        dropped["not_read"] = max(0, total - read)
    selection = Selection(
        candidates, dropped, read, total, source_size, size, by_content, timeline or None
    )
    if len(candidates) < (cfg.min_frames if fewest is None else fewest):
        raise InputError(too_few_frames(source, selection, cfg))
    return selection


def too_few_frames(source: InputSource, selection: Selection, cfg: IngestConfig) -> str:
    """'only 2 usable frame(s) in X (of 2); endopipe needs at least 3: give more frames'."""
    return (
        f"only {len(selection.frames)} usable frame(s) in {source.path} (of {selection.read}); "
        f"endopipe needs at least {cfg.min_frames}: {_more_frames_hint(cfg, selection.dropped)}"
    )


def _drop_reason(
    frame: Frame, position: int, cfg: IngestConfig, last_grey: np.ndarray | None
) -> str | None:
    """Why frame number `position` of the input is not a candidate, or None."""
    t = frame.time_s
    if t is not None and (t < cfg.start_s or (cfg.end_s is not None and t > cfg.end_s)):
        return "outside_time_window"
    if position % cfg.stride:
        return "stride"
    grey = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
    if np.percentile(grey, 99) < cfg.black_level:
        return "blank"
    if cfg.drop_duplicates and last_grey is not None:
        if frame_difference(grey, last_grey) < cfg.duplicate_threshold:
            return "duplicate"
    return None


def _sharp_enough(scores: list[float], cfg: IngestConfig) -> np.ndarray:
    """Which candidates pass the blur test (relative to their median sharpness; scores of 0:
    not judged here)."""
    values = np.asarray(scores, dtype=np.float64)
    if not cfg.drop_blurred or len(values) < 3 or not values.any():
        return np.ones(len(values), dtype=bool)
    return values >= cfg.blur_rel_threshold * np.median(values)


def _enough(scores: list[float], cfg: IngestConfig) -> bool:
    """Whether the candidates so far already give `max_frames` kept frames: decoding stops."""
    if cfg.max_frames is None or len(scores) < cfg.max_frames:
        return False
    return int(_sharp_enough(scores, cfg).sum()) >= cfg.max_frames


def _more_frames_hint(cfg: IngestConfig, dropped: dict[str, int]) -> str:
    """What would give more frames: only the settings that dropped some (never "lower the
    stride" when it is already 1)."""
    hints = ["give more frames (a longer video, more images)"]
    if cfg.stride > 1:
        hints.append(f"lower --set ingest.stride (now {cfg.stride})")
    if dropped.get("outside_time_window"):
        hints.append("widen --set ingest.start_s/end_s")
    if dropped.get("duplicate"):
        hints.append("--set ingest.drop_duplicates=false")
    if dropped.get("blurred"):
        hints.append("--set ingest.drop_blurred=false")
    if dropped.get("max_frames"):
        hints.append(f"raise --set ingest.max_frames (now {cfg.max_frames})")
    return ", or ".join(hints)


def working_size(width: int, height: int, max_size: int) -> tuple[int, int]:
    """(width, height) with the longer side at most `max_size` (downscale only)."""
    scale = min(1.0, max_size / max(width, height))
    return max(1, round(width * scale)), max(1, round(height * scale))


def resize(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    if (rgb.shape[1], rgb.shape[0]) == size:
        return rgb
    return cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
