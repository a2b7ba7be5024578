"""The poses' verdict (02_poses/verdict.json) on the page: ok, doubtful with the reasons, or not
assessed; which mapper was kept and why; the doubtful frames.

Why a block of its own: wrong SfM poses look fine in COLMAP's own numbers, and everything
downstream (NeRF, depth, mesh) inherits them, so a doubtful verdict has to be impossible to
miss: it is drawn like the other warnings of the page (`p.verdict`).
"""

from __future__ import annotations

from endopipe.stages.poses.verdict import FrameVerdict, PoseVerdict, ranges
from endopipe.stages.report.kit import fmt, grid, kv_table, not_available, text

#: Doubtful frames listed one per row; the rest are named as ranges.
MAX_FRAME_ROWS = 20
OLD_FOLDER = "no verdict (poses from an older version)"


def headline(verdict: PoseVerdict | None) -> str:
    """'Poses: ok', 'Poses: doubtful — <reasons>', 'Poses: not assessed — <why>' (text)."""
    if verdict is None:
        return f"Poses: {OLD_FOLDER}"
    reasons = "; ".join(verdict.reasons)
    if verdict.status == "doubtful" and not reasons:
        reasons = "no reason recorded"
    return f"Poses: {verdict.status}" + (f" — {reasons}" if reasons else "")


def headline_html(verdict: PoseVerdict | None) -> str:
    """The headline as a paragraph: red for doubtful (like the page's other warnings), green
    for ok, grey for not assessed or no verdict."""
    kind = {"doubtful": "", "ok": " ok"}.get(verdict.status if verdict else "", " muted")
    return f'<p class="verdict{kind}"><b>{text(headline(verdict))}</b></p>'


def evidence_rows(verdict: PoseVerdict) -> list[tuple[str, str]]:
    """Mapper kept, the others and why, the mappers' disagreement, the depth drift, the count
    of doubtful frames."""
    rows = [("Mapper kept", text(verdict.mapper or "—"))]
    for mapper, why in verdict.others.items():
        rows.append((f"{mapper} mapper (not kept)", text(why)))
    if verdict.disagreement_pct is not None:
        rows.append(
            (
                "Mappers' disagreement",
                fmt(verdict.disagreement_pct, "% of the path")
                + ' <span class="muted">(RMS distance between the two mappers\' cameras '
                "after a similarity)</span>",
            )
        )
    if verdict.depth_drift is not None:
        rows.append(
            (
                "Depth drift",
                f"{fmt(verdict.depth_drift)}×"
                + ' <span class="muted">(how many times the scene\'s median depth changes '
                "along the path; a scale drift shows here)</span>",
            )
        )
    registered = sum(f.status != "unregistered" for f in verdict.frames)
    bad = verdict.doubtful()
    shown = f"{len(bad)} of {registered} registered"
    if bad:
        shown += f": {ranges([f.index for f in bad])}"
    rows.append(("Doubtful frames", text(shown)))
    return rows


def frame_table(frames: list[FrameVerdict], limit: int = MAX_FRAME_ROWS) -> str:
    """The doubtful frames, one a row with their reasons (at most `limit`, then the rest)."""
    if not frames:
        return ""
    head = ["frame", "why doubtful", "points", "reprojection", "from the other mapper"]
    rows = [
        [
            fmt(f.index),
            text("; ".join(f.reasons) or "—"),
            fmt(f.points),
            fmt(f.reprojection_px, "px"),
            fmt(f.disagreement_pct, "% of the path"),
        ]
        for f in frames[:limit]
    ]
    out = grid(head, rows, "grid metrics", num=(0, 2, 3, 4))
    rest = frames[limit:]
    if rest:
        out += (
            f'<p class="note">and {len(rest)} more doubtful frame(s): '
            f"{text(ranges([f.index for f in rest]))}</p>"
        )
    return out


def verdict_block(verdict: PoseVerdict | None, error: str | None = None) -> str:
    """The poses section's verdict: the headline, then the evidence and the doubtful frames."""
    out = "<h3>Verdict on the poses</h3>"
    if error:
        return out + not_available(f"02_poses/verdict.json unreadable: {error}")
    out += headline_html(verdict)
    if verdict is None:
        return out
    if verdict.status == "not assessed":
        return out + (
            '<p class="note">Poses that come from the ground truth are not judged: there is '
            "nothing to check them against but themselves.</p>"
            if verdict.mapper == "gt"
            else ""
        )
    out += kv_table(evidence_rows(verdict))
    out += frame_table(verdict.doubtful())
    out += (
        '<p class="note">Judged without ground truth (02_poses/verdict.json): a frame is doubtful '
        "when it sees few triangulated points, reprojects badly, jumps or turns far more than "
        "its neighbours, or sits far from the other mapper's camera; the sequence when its "
        "scale drifts, the mappers disagree, or too many frames are doubtful or unregistered."
        "</p>"
    )
    return out
