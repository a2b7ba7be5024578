"""The poses' verdict (02_poses/verdict.json) on the page: ok, doubtful with the reasons, or not
assessed; which mapper was kept and why; the doubtful frames.

Why a block of its own: wrong SfM poses look fine in COLMAP's own numbers, and everything
downstream (NeRF, depth, mesh) inherits them, so a doubtful verdict has to be impossible to
miss: it is drawn like the other warnings of the page (`p.verdict`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

from endopipe.stages.poses.verdict import FrameVerdict, PoseVerdict, ranges
from endopipe.stages.report.kit import macro

#: Doubtful frames listed one per row; the rest are named as ranges.
MAX_FRAME_ROWS = 20
OLD_FOLDER = "no verdict (poses from an older version)"
TEMPLATE = "sections/verdict.html.j2"


def headline(verdict: PoseVerdict | None) -> str:
    """'Poses: ok', 'Poses: doubtful — <reasons>', 'Poses: not assessed — <why>' (text)."""
    if verdict is None:
        return f"Poses: {OLD_FOLDER}"
    reasons = "; ".join(verdict.reasons)
    if verdict.status == "doubtful" and not reasons:
        reasons = "no reason recorded"
    return f"Poses: {verdict.status}" + (f" — {reasons}" if reasons else "")


@dataclass(frozen=True)
class VerdictBlock:
    """A verdict (None: a folder written before verdicts) as the page shows it; `error`: why
    verdict.json could not be read."""

    verdict: PoseVerdict | None
    error: str | None = None
    limit: int = MAX_FRAME_ROWS

    @property
    def headline(self) -> str:
        return headline(self.verdict)

    @property
    def status(self) -> str:
        return self.verdict.status if self.verdict is not None else ""

    @property
    def tone(self) -> str:
        """The headline's colour: red for doubtful, green for ok, grey otherwise."""
        return {"doubtful": "", "ok": "ok"}.get(self.status, "muted")

    @property
    def badge(self) -> str:
        return {"ok": "ok", "doubtful": "bad"}.get(self.status, "muted")

    @cached_property
    def doubtful(self) -> list[FrameVerdict]:
        return self.verdict.doubtful() if self.verdict is not None else []

    @property
    def shown(self) -> list[FrameVerdict]:
        """The doubtful frames given a row each."""
        return self.doubtful[: self.limit]

    @property
    def rest(self) -> str:
        """The doubtful frames beyond the rows, as ranges ('' when none)."""
        return ranges([f.index for f in self.doubtful[self.limit :]])

    @property
    def doubtful_count(self) -> str:
        """'2 of 5 registered: 1-2'."""
        registered = sum(f.status != "unregistered" for f in self.verdict.frames)
        shown = f"{len(self.doubtful)} of {registered} registered"
        return shown + (f": {ranges([f.index for f in self.doubtful])}" if self.doubtful else "")


def frame_table(frames: list[FrameVerdict], limit: int = MAX_FRAME_ROWS) -> str:
    """The doubtful ones of `frames`, one a row with their reasons (at most `limit`, then the
    rest as ranges): the table of the poses section on its own."""
    block = VerdictBlock(PoseVerdict(status="doubtful", frames=frames), limit=limit)
    return str(macro(TEMPLATE, "frame_table")(block))
