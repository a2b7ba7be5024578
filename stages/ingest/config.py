"""The ingest stage's settings: frame selection, working resolution and the masks."""

from __future__ import annotations

from pydantic import Field

from endopipe.pipeline.stage import StageConfig
from endopipe.stages.ingest.masks import FovConfig, SpecularConfig


class IngestConfig(StageConfig):
    stride: int = Field(1, ge=1, description="Keep every n-th frame of the input.")
    max_frames: int | None = Field(
        None, ge=1, description="Keep at most this many frames (after stride and filtering)."
    )
    start_s: float = Field(0.0, ge=0, description="Skip video before this time (seconds).")
    end_s: float | None = Field(None, gt=0, description="Stop reading the video at this time.")
    max_size: int = Field(
        320,
        ge=32,
        description="Working resolution: the longer image side, in pixels (downscale only).",
    )
    min_frames: int = Field(3, ge=2, description="Fewer usable frames than this is an error.")
    drop_duplicates: bool = Field(
        True, description="Drop frames nearly identical to the last kept one."
    )
    duplicate_threshold: float = Field(
        0.0015,
        ge=0,
        description="Mean absolute grey difference (0..1) under which a frame is a duplicate.",
    )
    drop_blurred: bool = Field(
        True, description="Drop frames much blurrier than the sequence median."
    )
    blur_rel_threshold: float = Field(
        0.35,
        ge=0,
        le=1,
        description="A frame is blurred when its sharpness < this x the median sharpness.",
    )
    black_level: float = Field(
        8.0, ge=0, description="A frame whose 99th-percentile grey level is under this is blank."
    )
    fov: FovConfig = Field(
        default_factory=FovConfig, description="Field-of-view (scope border) mask."
    )
    specular: SpecularConfig = Field(
        default_factory=SpecularConfig, description="Specular-highlight mask."
    )
    contact_sheet_frames: int = Field(16, ge=1, description="Frames shown in contact_sheet.png.")
