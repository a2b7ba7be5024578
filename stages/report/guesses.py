"""Ours beside the two guesses (stages.metrics.baselines): the table, and the sentences that
say in words when ours does not beat a guess. Reads the depth stage's metrics.json as a dict."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from endopipe.stages.report.kit import fmt, grid, text

#: What each guess assumes, for the table's head and the sentences.
GUESS_LABELS = {
    "radial": ("radial guess", "the image centre is far"),
    "brightness": ("brightness guess", "inverse-square shading, depth = 1/√brightness"),
}


@dataclass(frozen=True)
class Headline:
    """One row of the comparison: a metric of one protocol block."""

    protocol: str
    key: str
    name: str
    how: str  # the protocol, in words
    higher_is_better: bool

    @property
    def label(self) -> str:
        return f"{self.name}, {self.how}" if self.how else self.name


#: Rows for a metric ground truth (exact, pseudo); the first one decides the sentences.
METRIC_ROWS = (
    Headline("median_scaled", "abs_rel", "AbsRel", "per-frame median scaling", False),
    Headline("median_scaled", "delta1", "δ < 1.25", "per-frame median scaling", True),
    Headline("sequence_scaled", "abs_rel", "AbsRel", "one scale for the sequence", False),
    Headline("median_scaled", "coverage", "Coverage", "", True),
)
#: Rows for a relative ground truth (depth up to scale and shift): ranking first.
RELATIVE_ROWS = (
    Headline("affine_invariant", "spearman", "Spearman ρ", "ranking of pixels", True),
    Headline("affine_invariant", "abs_rel", "AbsRel", "scale and shift fitted", False),
    Headline("affine_invariant", "coverage", "Coverage", "", True),
)


def headline_rows(metrics: dict) -> tuple[Headline, ...]:
    """The rows this metrics.json supports (none without a protocol block)."""
    if isinstance(metrics.get("median_scaled"), dict):
        return METRIC_ROWS
    if isinstance(metrics.get("affine_invariant"), dict):
        return RELATIVE_ROWS
    return ()


def value(block: Any, row: Headline) -> float | None:
    """`row`'s number in a metrics block (ours, or one guess's), None when absent or NaN."""
    v = (block or {}).get(row.protocol, {}).get(row.key) if isinstance(block, dict) else None
    ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
    return float(v) if ok else None


def guesses(metrics: dict) -> dict[str, dict]:
    """The guesses' blocks in display order ({} when metrics.json has none)."""
    found = metrics.get("baselines")
    if not isinstance(found, dict):
        return {}
    return {name: found[name] for name in GUESS_LABELS if isinstance(found.get(name), dict)}


def verdicts(metrics: dict) -> list[str]:
    """One sentence per guess that ours does not beat on the headline metric (the first
    row: AbsRel after per-frame median scaling, or Spearman ρ for a relative ground truth)."""
    rows = headline_rows(metrics)
    if not rows:
        return []
    head = rows[0]
    ours = value(metrics, head)
    out = []
    for name, block in guesses(metrics).items():
        theirs = value(block, head)
        if ours is None or theirs is None:
            continue
        beaten = ours > theirs if head.higher_is_better else ours < theirs
        if beaten:
            continue
        label, idea = GUESS_LABELS[name]
        how = (
            "ranks pixels no better than" if head.key == "spearman" else "is no more accurate than"
        )
        out.append(
            f"On this case our depth {how} the {label} ({idea}): {head.name} {ours:.3g} "
            f"for ours against {theirs:.3g} for the guess ({head.how})."
        )
    return out


def comparison(metrics: dict) -> str:
    """The table ours | radial | brightness on the headline metrics, the note on the pixels,
    and the verdicts (or the one sentence saying ours beats both). Empty without guesses."""
    rows, found = headline_rows(metrics), guesses(metrics)
    if not rows or not found:
        return ""
    cells = []
    for row in rows:
        arrow = "↑" if row.higher_is_better else "↓"
        head = f'{text(row.label)} <span class="muted">{arrow}</span>'
        cells.append(
            [head, fmt(value(metrics, row)), *(fmt(value(b, row)) for b in found.values())]
        )
    names = ["ours", *(GUESS_LABELS[n][0] for n in found)]
    table = grid(names, cells, "grid metrics", num=tuple(range(len(names))), row_head=True)
    ideas = "; ".join(f"{GUESS_LABELS[n][0]}: {GUESS_LABELS[n][1]}" for n in found)
    note = (
        f'<p class="note">Two guesses that look at no geometry ({text(ideas)}), scored with '
        "the same protocols on exactly the pixels ours is scored on (valid ground truth inside "
        "the field of view, where ours has a depth), so their coverage is ours. A "
        "reconstruction that does not beat them has not recovered the scene.</p>"
    )
    said = verdicts(metrics)
    words = "".join(f'<p class="verdict"><b>{text(s)}</b></p>' for s in said)
    compared = value(metrics, rows[0]) is not None and all(
        value(b, rows[0]) is not None for b in found.values()
    )
    if compared and not said:
        words = f'<p class="note">Ours beats every guess on {text(rows[0].label)}.</p>'
    return "<h3>Against two guesses</h3>" + table + note + words
