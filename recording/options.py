"""How a recording is cut into windows and joined: the one place its settings and their
defaults are declared (`endopipe run` and `endopipe batch` take their options from here)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator


class RecordingOptions(BaseModel):
    """A long input's windows: their length, what neighbours share, how they are posed and how
    the joined path's scale is kept."""

    model_config = ConfigDict(extra="forbid")

    window: int = Field(100, ge=8, description="A recording (long input): keyframes per window.")
    overlap: int = Field(
        12, ge=3, description="A recording: keyframes shared by neighbouring windows."
    )
    light_scale: bool = Field(
        True,
        description="A recording: redraw the joined path for the scale drift the light measures "
        "(assumes a fixed exposure; off for a scope with auto-exposure).",
    )
    one_sfm_up_to: int = Field(
        200,
        ge=0,
        description="A recording of at most this many keyframes is posed by one SfM and its "
        "lumen fitted once; the windows then split only the field (0: each window its own SfM).",
    )

    @field_validator("overlap")
    @classmethod
    def _under_window(cls, overlap: int, info: ValidationInfo) -> int:
        """Neighbouring windows are joined on the cameras they share: fewer than the window."""
        window = info.data.get("window")
        if window is not None and overlap >= window:
            raise ValueError(f"{overlap} keyframes shared is not under the window's {window}")
        return overlap
