"""The ingest stage's settings: frame selection, working resolution and the masks."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from endopipe.pipeline.stage import StageConfig

# The mask settings live here, not in masks.py, so reading the config needs no OpenCV.
FovShape = Literal["circle", "octagon", "rectangle", "full"]


class FovConfig(BaseModel):
    """How the endoscope's field of view is found."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(True, description="Find the field of view; when off the mask is all 255.")
    black_threshold: int = Field(
        25,
        ge=0,
        le=255,
        description="Brightness (max of R, G, B) under which a pixel connected to the image edge "
        "is scope border.",
    )
    erode_px: int = Field(
        3, ge=0, description="Shrink the found region by this many pixels (dark vignetting rim)."
    )
    open_frac: float = Field(
        0.02,
        ge=0.0,
        le=0.2,
        description="Opening kernel, as a fraction of the short image side: removes burned-in "
        "text, thin lines and other small bright bits lying in the border.",
    )
    full_frac: float = Field(
        0.99,
        gt=0.0,
        le=1.0,
        description="If the bright region's hull covers at least this fraction of the image, "
        "there is no border: shape 'full'.",
    )
    rectangle_fill: float = Field(
        0.97,
        gt=0.0,
        le=1.0,
        description="If the hull fills at least this fraction of its bounding box, shape "
        "'rectangle' (black bars only).",
    )
    circle_tol: float = Field(
        0.012,
        gt=0.0,
        description="Largest RMS distance of the hull outline from a fitted circle, relative to "
        "its radius, for shape 'circle'; otherwise the hull polygon is kept ('octagon').",
    )
    cut_overlays: bool = Field(
        True,
        description="Also exclude solid patches that the fitted shape spans but that are not "
        "tissue: border-black boxes burned into a corner, coloured boxes framed in black. "
        "Static overlays mislead pose estimation. Off gives the pure convex shape.",
    )
    sample_frames: int = Field(
        15, ge=1, description="Frames sampled evenly from a sequence to estimate its one mask."
    )
    sequence_percentile: float = Field(
        90.0,
        ge=0.0,
        le=100.0,
        description="Per-pixel percentile of brightness over the sampled frames: high, so a dark "
        "lumen in some frames is seen bright in others, yet below 100 to ignore odd flashes.",
    )


class SpecularConfig(BaseModel):
    """How specular highlights are found (bright, white, small blobs)."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(True, description="Find highlights; when off nothing is flagged.")
    min_value: int = Field(
        245,
        ge=0,
        le=255,
        description="Absolute test: HSV value (0..255) at or above which a white pixel is a "
        "highlight (saturated highlights clip near 255).",
    )
    max_saturation: int = Field(
        12,
        ge=0,
        le=255,
        description="Absolute test: HSV saturation (0..255) at or under which a bright pixel is "
        "white. Low, so pale pink tissue (V ~245, S ~20-40) is not taken for a highlight.",
    )
    rel_ratio: float = Field(
        1.25,
        gt=1.0,
        description="Relative test: whiteness (min of R, G, B) at least this many times the "
        "local background's marks an unsaturated highlight on darker tissue.",
    )
    rel_min_white: int = Field(
        170,
        ge=0,
        le=255,
        description="Relative test: whiteness (min of R, G, B) a pixel needs at least. Red "
        "tissue has a low blue channel however bright it is, so this also rejects colour.",
    )
    background_frac: float = Field(
        0.08,
        gt=0.0,
        le=0.5,
        description="Size of the median filter that estimates the local background, as a "
        "fraction of the short image side.",
    )
    min_blob_px: int = Field(
        3, ge=0, description="Candidate blobs smaller than this (pixels) are noise, not kept."
    )
    dilate_px: int = Field(
        2, ge=0, description="Grow kept highlights by this many pixels to cover their halo."
    )


class ToolsConfig(BaseModel):
    """Surgical tools in view: masks given with the input, or found in the frames."""

    model_config = ConfigDict(extra="forbid")

    polarity: Literal["auto", "white_is_tool", "black_is_tool"] = Field(
        "auto",
        description="How given tool masks (masks/) are read. auto: 255 = tool (EndoNeRF's "
        "convention), and a mask marking over 60% of its frame as tool is refused as the other "
        "polarity; white_is_tool / black_is_tool: read as said, never refused.",
    )
    detect: Literal["auto", "off"] = Field(
        "auto",
        description="auto: find tools when the input gives no masks: grey metal (low "
        "saturation, not dark, not warm) in large regions that reach the border of the view "
        "(0.0% of the pixels marked on four real clips without tools, the da Vinci instrument "
        "found on EndoNeRF's cutting clip: docs/experiments.md); off: never.",
    )

    @field_validator("detect", mode="before")
    @classmethod
    def _detect_off(cls, v: object) -> object:
        """`--set ingest.tools.detect=off` arrives as YAML's False."""
        return "off" if v is False else v

    max_saturation: int = Field(
        60,
        ge=0,
        le=255,
        description="Detection: HSV saturation (0..255) at or under which a pixel may be metal.",
    )
    min_value: int = Field(
        60, ge=0, le=255, description="Detection: HSV value under which a pixel is too dark."
    )
    min_area: float = Field(
        0.01,
        ge=0,
        le=1,
        description="Detection: smallest region kept as a tool, a share of the frame.",
    )
    max_share: float = Field(
        0.4,
        gt=0,
        le=1,
        description="Detection: what would cover more than this share of the field of view is "
        "the scene (a grey phantom, a blank frame), not a tool: nothing is marked.",
    )
    min_blue_minus_red: float = Field(
        0.0,
        description="Detection: a region's mean blue minus red (0..255) must reach this: metal "
        "is neutral or cool, pale tissue warm.",
    )
    grow: float = Field(
        0.01,
        ge=0,
        le=0.1,
        description="Detection: grow each found tool by this share of the short image side (3 "
        "px at 256): its rim (the shaft's shaded, blended edge, a thin jaw the smoothing cut "
        "off) is the tool's, not tissue. EndoNeRF's cutting clip, held-out PSNR of one "
        "trained field on the pixels clear of the tool grown by 0 / 1 / 3 px: 31.28 / 31.63 / "
        "31.91 dB (docs/experiments.md). Masks given with the input are used as given.",
    )


class KeyframeConfig(BaseModel):
    """When and how ingest keeps frames by content instead of keeping every usable one."""

    model_config = ConfigDict(extra="forbid")

    mode: Literal["auto", "content", "all"] = Field(
        "auto",
        description="content: keep a frame when the view has moved enough since the last kept "
        "one; all: every usable frame; auto: content for inputs of more than auto_above frames "
        "(a short clip keeps all its frames).",
    )
    auto_above: int = Field(300, ge=1, description="auto: inputs longer than this are recordings.")
    min_flow: float = Field(
        0.01,
        gt=0,
        description="Keep a frame once the tracked corners have moved this far (median, a "
        "fraction of the image diagonal) since the last keyframe (a synthetic colon "
        "withdrawal: a keyframe every 0.9 mm, the spacing of the bench's frames).",
    )
    still_flow: float = Field(
        0.001,
        ge=0,
        description="A frame whose corners moved less than this (fraction of the diagonal) "
        "since the frame before shows a camera standing still.",
    )
    washed_out: float = Field(
        0.2,
        gt=0,
        le=1,
        description="A frame with more than this fraction of its pixels saturated (grey >= "
        "250) is washed out by the light (usable frames of the synthetic colon: 0-1.3%; "
        "washed-out ones 32-57%).",
    )
    blur_window: int = Field(
        31, ge=3, description="Frames in the running median that blur is judged against."
    )
    track_size: int = Field(160, ge=32, description="Long side of the grey copies tracked, px.")
    corners: int = Field(200, ge=10, description="Corners tracked from each keyframe.")
    min_tracked: float = Field(
        0.3,
        gt=0,
        le=1,
        description="When fewer than this fraction of a keyframe's corners are still tracked, "
        "the view has changed: the frame is kept.",
    )


class StereoConfig(BaseModel):
    """Metric depth from the input's rectified right views (stereo.py), when it has them."""

    model_config = ConfigDict(extra="forbid")

    mode: Literal["auto", "on", "off"] = Field(
        "auto",
        description="auto: match when the input comes with right views and a baseline (Hamlyn's "
        "image02/); on: the same, and an input without them is an error; off: never.",
    )
    check: bool = Field(
        True,
        description="Check the rig against its images before matching (features matched "
        "between the eyes): pair each left frame with the right frame of the same moment and "
        "shift the right image by the rows the rectification leaves (ingest/rig_check.py).",
    )
    max_offset: int = Field(
        2, ge=0, le=5, description="The check tries right frames up to this many away."
    )
    min_depth_mm: float = Field(
        4.0,
        gt=0,
        description="The nearest depth searched for: sets the disparity range (fx x baseline / "
        "this, at most half the image width).",
    )
    min_disparity_px: float = Field(
        5.0,
        gt=0,
        description="Matches under this disparity (px at the working size) are left unknown: "
        "too far for the baseline to measure well (half a pixel off is 10% of the depth there).",
    )
    matcher_mode: Literal["hh", "hh4", "3way", "sgbm"] = Field(
        "hh",
        description="StereoSGBM's mode: hh, the full 8-path pass (scripts/stereo_matchers.py: "
        "AbsRel a quarter lower than 3way on the synthetic stereo cases, 4% on the real Hamlyn "
        "clip, 1.5x the time); hh4 most of that at 3way's speed; 3way; sgbm (5 paths).",
    )
    block_size: int = Field(5, ge=1, le=11, description="StereoSGBM's matched block, px (odd).")
    uniqueness: int = Field(
        10,
        ge=0,
        le=100,
        description="StereoSGBM's uniqueness ratio, %: the best match must beat the second by it.",
    )
    lr_max_diff_px: float = Field(
        1.0,
        ge=0,
        description="Left-right check: a pixel keeps its depth when the right image's match "
        "points back within this many px.",
    )
    speckle_window: int = Field(
        100, ge=0, description="Disparity blobs smaller than this (px) are noise, left unknown."
    )
    speckle_range: int = Field(
        2, ge=0, description="Disparity spread (px) within which neighbours form one blob."
    )

    @field_validator("mode", mode="before")
    @classmethod
    def _yaml_words(cls, v: object) -> object:
        """`--set ingest.stereo.mode=off` reaches here as YAML's false (and on as true)."""
        return {False: "off", True: "on"}.get(v, v) if isinstance(v, bool) else v

    @field_validator("block_size")
    @classmethod
    def _odd(cls, v: int) -> int:
        if v % 2 == 0:
            raise ValueError("must be odd")
        return v


class IngestConfig(StageConfig):
    stride: int = Field(1, ge=1, description="Keep every n-th frame of the input.")
    max_frames: int | None = Field(
        None,
        ge=1,
        description="Keep at most this many frames (after stride and filtering); decoding "
        "stops once they are kept.",
    )
    frames: list[int] | None = Field(
        None,
        description="Keep only the input frames at these positions (source_index, ascending): "
        "a window of a recording; decoding stops after the last.",
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
    keyframes: KeyframeConfig = Field(
        default_factory=KeyframeConfig,
        description="Long recordings: frames kept by content (motion since the last kept one), "
        "not by stride; washed-out, blurred and still frames dropped, each counted.",
    )
    fov: FovConfig = Field(
        default_factory=FovConfig, description="Field-of-view (scope border) mask."
    )
    specular: SpecularConfig = Field(
        default_factory=SpecularConfig, description="Specular-highlight mask."
    )
    tools: ToolsConfig = Field(
        default_factory=ToolsConfig,
        description="Surgical tools: their pixels leave the usable mask (the photometric loss).",
    )
    contact_sheet_frames: int = Field(16, ge=1, description="Frames shown in contact_sheet.png.")
    stereo: StereoConfig = Field(
        default_factory=StereoConfig,
        description="Metric depth per frame from the input's right views (01_ingest/stereo/).",
    )
