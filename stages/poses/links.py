"""Where a reconstruction holds together by only a few points.

Why: a mapper keeps every frame it can place in one model, however weakly the frames are tied.
On a real sinus recording the scope moved about nine times faster a frame for its last 25
frames; those keyframes shared 2-3 triangulated points with the frames before them, and the
global mapper kept them in its one model turned 61 degrees from the rest of the path (right
among themselves, wrong against the rest). No residual shows it: every point reprojects well.
What shows it is the link itself: the triangulated points whose tracks span the cut between
two consecutive frames. Healthy models hold together by 160-540 points at their weakest cut (the
C3VD preview, the bench colon, the windows of a synthetic withdrawal); the sinus by 2-3.

Points span a cut more thinly where features are few, so a cut is judged against the points
its neighbourhood sees: the share of the points seen by the `NEAR` frames on its thinner side
(before or after) that are also seen across it. Healthy models: 0.70 or more at every cut (eight
models: the C3VD preview, the bench colon, five windows of a synthetic withdrawal); the sinus's
wrongly glued stretch: 0.23. A cut under `VerdictConfig.min_link_share` is weak: the frames on
either side are placed against each other by little but those points. The verdict calls the cut
out, and a recording poses the stretches on either side as separate segments
(docs/recordings.md).
"""

from __future__ import annotations

from collections.abc import Collection

import numpy as np
from pydantic import BaseModel, Field


class WeakLink(BaseModel):
    """A cut between two consecutive registered frames that few points span."""

    after: int = Field(description="The last registered frame before the cut (frame index).")
    before: int = Field(description="The first registered frame after it.")
    points: int = Field(description="Triangulated points seen on both sides of the cut.")
    share: float = Field(
        description="Those points' share of the points seen near the cut, on its thinner side."
    )


#: Frames on each side of a cut whose points it is judged against.
NEAR = 3


def link_strength(seen: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """For each cut k (between registered frames k and k+1, in frame order): how many points are
    seen both at or before k and after it, and their share of the points the `NEAR` frames on
    the thinner side see. `seen[k]`: the ids of the points frame k sees."""
    n = len(seen)
    first: dict[int, int] = {}
    last: dict[int, int] = {}
    for k, ids in enumerate(seen):
        for p in ids.tolist():
            first.setdefault(p, k)
            last[p] = k
    change = np.zeros(n + 1, dtype=np.int64)
    for p, lo in first.items():
        if last[p] > lo:
            change[lo] += 1
            change[last[p]] -= 1
    points = np.cumsum(change)[: max(n - 1, 0)]
    share = np.ones(len(points))
    for k in range(len(points)):
        before = np.unique(np.concatenate(seen[max(0, k - NEAR + 1) : k + 1]))
        after = np.unique(np.concatenate(seen[k + 1 : k + 1 + NEAR]))
        share[k] = points[k] / max(min(len(before), len(after)), 1)
    return points, share


def weak_links(
    index: np.ndarray, points: np.ndarray, share: np.ndarray, min_share: float
) -> list[WeakLink]:
    """The cuts whose share is under `min_share`; `index` the registered frames in order,
    `points` and `share` from `link_strength`."""
    return [
        WeakLink(
            after=int(index[k]),
            before=int(index[k + 1]),
            points=int(points[k]),
            share=round(float(share[k]), 3),
        )
        for k in np.flatnonzero(share < min_share)
    ]


def stretches(index: np.ndarray, links: list[WeakLink]) -> list[list[int]]:
    """The registered frames cut at the weak links: each stretch holds together by many points."""
    return split_at([int(i) for i in index], {link.before for link in links})


def split_at(frames: list[int], starts: Collection[int]) -> list[list[int]]:
    """Frames in order, cut before each of `starts`."""
    out: list[list[int]] = []
    for i in frames:
        if not out or i in starts:
            out.append([])
        out[-1].append(i)
    return out


def cutting_links(index: np.ndarray, links: list[WeakLink], min_frames: int = 3) -> list[WeakLink]:
    """The weak links a model is cut at: where a stretch between them would hold fewer than
    `min_frames` frames (too few to reconstruct on its own), it stays with the neighbour it is
    linked to more strongly, and that link is not cut."""
    cut = sorted(links, key=lambda link: link.before)
    while True:
        parts = stretches(index, cut)
        short = next((k for k, part in enumerate(parts) if len(part) < min_frames), None)
        if short is None or not cut:
            return cut
        bounding = [cut[k] for k in (short - 1, short) if 0 <= k < len(cut)]
        cut.remove(max(bounding, key=lambda link: link.share))
