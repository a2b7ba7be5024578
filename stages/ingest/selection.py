"""Which input frames ingest keeps: time window, stride, and blank / duplicate / blurred
frames dropped, each reason counted for the summary."""

from __future__ import annotations

import cv2
import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.pipeline.stage import StageContext
from endopipe.stages.ingest.config import IngestConfig
from endopipe.stages.ingest.frame_quality import frame_difference, sharpness
from endopipe.stages.io.sources import Frame, InputSource


def select_frames(
    source: InputSource, cfg: IngestConfig, ctx: StageContext
) -> tuple[list[Frame], dict[str, int], int]:
    """Stride, time window, blank / duplicate / blur filtering; reasons are counted."""
    dropped = {"outside_time_window": 0, "stride": 0, "blank": 0, "duplicate": 0, "blurred": 0}
    candidates: list[Frame] = []
    total = 0
    last_grey: np.ndarray | None = None
    with ctx.progress("decode", total=source.frame_count()) as advance:
        for frame in source.frames():
            total += 1
            advance()
            t = frame.time_s
            if t is not None and (t < cfg.start_s or (cfg.end_s is not None and t > cfg.end_s)):
                dropped["outside_time_window"] += 1
                continue
            if (total - 1) % cfg.stride:
                dropped["stride"] += 1
                continue
            grey = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
            if np.percentile(grey, 99) < cfg.black_level:
                dropped["blank"] += 1
                continue
            if cfg.drop_duplicates and last_grey is not None:
                if frame_difference(grey, last_grey) < cfg.duplicate_threshold:
                    dropped["duplicate"] += 1
                    continue
            last_grey = grey
            candidates.append(frame)
    if total == 0:
        raise InputError(f"{source.path} holds no decodable frames; check the file")
    if not candidates:
        raise InputError(
            f"all {total} frames of {source.path} are blank (black) or outside the time window; "
            "check the video and --set ingest.start_s/end_s"
        )
    if cfg.drop_blurred and len(candidates) >= 3:
        scores = np.array([sharpness(f.rgb) for f in candidates])
        keep = scores >= cfg.blur_rel_threshold * np.median(scores)
        dropped["blurred"] = int((~keep).sum())
        candidates = [f for f, k in zip(candidates, keep, strict=True) if k]
    if cfg.max_frames is not None:
        candidates = candidates[: cfg.max_frames]
    if len(candidates) < cfg.min_frames:
        raise InputError(
            f"only {len(candidates)} usable frame(s) in {source.path} (of {total}); endopipe needs "
            f"at least {cfg.min_frames}: give a longer video or lower --set ingest.stride"
        )
    return candidates, dropped, total
