"""Command-line options declared once, as frozen dataclasses whose field metadata holds each
option's help and lower bound (`{"help": ..., "min": ...}`): the command line builds its options
from them at start-up (without pydantic, so `endopipe --help` stays fast), and the dataclass
checks its values when built. A refused value is a ValueError(field name, reason)."""

from __future__ import annotations

import dataclasses
from typing import Any


def check_bounds(options: Any) -> None:
    """Every field at or above its declared `min` (None, an unset option, passes)."""
    for f in dataclasses.fields(options):
        low, value = f.metadata.get("min"), getattr(options, f.name)
        if low is not None and value is not None and value < low:
            raise ValueError(f.name, f"{value} is below the minimum {low}")
