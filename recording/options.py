"""How a recording is cut into windows and joined: the one place its settings and their
defaults are declared (`endopipe run` and `endopipe batch` take their options from here).

A dataclass, not a pydantic model: the command line reads it at start-up, and `endopipe --help`
must not wait for pydantic. Each field's metadata holds its help and lower bound."""

from __future__ import annotations

from dataclasses import dataclass, field

from endopipe.pipeline.options import check_bounds


@dataclass(frozen=True)
class RecordingOptions:
    """A long input's windows: their length, what neighbours share, how they are posed and how
    the joined path's scale is kept."""

    window: int = field(
        default=100, metadata={"min": 8, "help": "A recording (long input): keyframes per window."}
    )
    overlap: int = field(
        default=12,
        metadata={"min": 3, "help": "A recording: keyframes shared by neighbouring windows."},
    )
    light_scale: bool = field(
        default=True,
        metadata={
            "help": "A recording: redraw the joined path for the scale drift the light measures "
            "(assumes a fixed exposure; off for a scope with auto-exposure)."
        },
    )
    one_sfm_up_to: int = field(
        default=200,
        metadata={
            "min": 0,
            "help": "A recording of at most this many keyframes is posed by one SfM and its lumen "
            "fitted once; the windows then split only the field (0: each window its own SfM).",
        },
    )

    def __post_init__(self) -> None:
        check_bounds(self)
        if self.overlap >= self.window:
            # neighbouring windows are joined on the cameras they share: fewer than the window
            raise ValueError(
                "overlap",
                f"{self.overlap} keyframes shared is not under the window's {self.window}",
            )
