"""The wording every input error shares, so each reader says what to do in the same words."""

from __future__ import annotations

#: What endopipe reads, appended to an error about an input it cannot use.
HINT = "give a video (mp4, avi, mov, mkv), a folder of images, or an endopipe case folder"


def short_reason(e: BaseException) -> str:
    """A library's exception as one short line: its first line, or its type when it has none."""
    text = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    return text[:160]
