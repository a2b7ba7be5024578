"""The number in a file's name: how every reader matches a data set's files to frames.

Copies of a data set pad numbers differently (`000012.png`, `frame-12.mask.png`,
`0000000012.jpg`), so a file belongs to the frame whose file carries the same number, and one
rule for that number serves every reader (tool masks, depth maps, right views, a COLMAP
model's images)."""

from __future__ import annotations

import re
from pathlib import Path


def file_number(path: Path | str) -> int | None:
    """The last number before the name's first dot (`frame-000012.color.png` -> 12), else the
    last in its stem; None without one."""
    name = Path(path).name
    digits = re.findall(r"\d+", name.split(".")[0]) or re.findall(r"\d+", Path(name).stem)
    return int(digits[-1]) if digits else None
