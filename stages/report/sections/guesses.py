"""Ours beside the two guesses (stages.metrics.baselines): the table, and the sentences that
say in words when ours does not beat a guess."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from endopipe.stages.metrics.scores import DepthScores, ProtocolScores

if TYPE_CHECKING:
    from endopipe.stages.depth.view import DepthMetrics

#: What each guess assumes, for the table's head and the sentences.
GUESS_LABELS = {
    "radial": ("radial guess", "the image centre is far"),
    "brightness": ("brightness guess", "inverse-square shading, depth = 1/√brightness"),
    "stereo": ("stereo matcher", "the rig's own depth, left-right checked"),
    "depth_prior": ("your depth prior", "the --depth-prior maps, median-scaled as ours are"),
    "shading": (
        "depth from shading",
        "the light's fall-off alone: 1/√(blurred linear brightness), a still camera's",
    ),
}


@dataclass(frozen=True)
class Headline:
    """One row of the comparison: a score of one protocol block."""

    name: str
    how: str  # the protocol, in words
    higher_is_better: bool
    block: Callable[[ProtocolScores], DepthScores | None]
    score: Callable[[DepthScores], float | None]
    ranking: bool = False  # a rank correlation: the sentence says "ranks pixels"

    @property
    def label(self) -> str:
        return f"{self.name}, {self.how}" if self.how else self.name

    def value(self, scores: ProtocolScores) -> float | None:
        """This row's number in `scores` (ours, or a guess's), None when absent or NaN."""
        block = self.block(scores)
        v = self.score(block) if block is not None else None
        return float(v) if v is not None and math.isfinite(v) else None


MEDIAN = "per-frame median scaling"
#: Rows for a metric ground truth (exact, pseudo); the first one decides the sentences.
METRIC_ROWS = (
    Headline("AbsRel", MEDIAN, False, lambda p: p.median_scaled, lambda s: s.abs_rel),
    Headline("δ < 1.25", MEDIAN, True, lambda p: p.median_scaled, lambda s: s.delta1),
    Headline(
        "AbsRel",
        "one scale for the sequence",
        False,
        lambda p: p.sequence_scaled,
        lambda s: s.abs_rel,
    ),
    Headline("Coverage", "", True, lambda p: p.median_scaled, lambda s: s.coverage),
)
#: Rows for a relative ground truth (depth up to scale and shift): ranking first.
RELATIVE_ROWS = (
    Headline(
        "Spearman ρ",
        "ranking of pixels",
        True,
        lambda p: p.affine_invariant,
        lambda s: s.spearman,
        ranking=True,
    ),
    Headline(
        "AbsRel", "scale and shift fitted", False, lambda p: p.affine_invariant, lambda s: s.abs_rel
    ),
    Headline("Coverage", "", True, lambda p: p.affine_invariant, lambda s: s.coverage),
)


def ours(metrics: DepthMetrics) -> ProtocolScores:
    """The depth stage's own blocks, in the shape of a guess's."""
    return ProtocolScores(
        median_scaled=metrics.median_scaled,
        sequence_scaled=metrics.sequence_scaled,
        unscaled=metrics.unscaled,
        affine_invariant=metrics.affine_invariant,
        frames=metrics.frames,
    )


#: With metric poses: the depth as it is, in millimetres.
UNSCALED_ROW = Headline(
    "AbsRel", "no scaling (metric poses)", False, lambda p: p.unscaled, lambda s: s.abs_rel
)


def headline_rows(scores: ProtocolScores) -> tuple[Headline, ...]:
    """The rows these scores support (none without a protocol block)."""
    if scores.median_scaled is not None:
        return METRIC_ROWS + ((UNSCALED_ROW,) if scores.unscaled is not None else ())
    if scores.affine_invariant is not None:
        return RELATIVE_ROWS
    return ()


def guesses(metrics: DepthMetrics) -> dict[str, ProtocolScores]:
    """The guesses' blocks in display order ({} when metrics.json has none)."""
    found = metrics.baselines or {}
    return {name: found[name] for name in GUESS_LABELS if name in found}


def verdicts(metrics: DepthMetrics) -> list[str]:
    """One sentence per guess that ours does not beat on the headline score (the first row:
    AbsRel after per-frame median scaling, or Spearman ρ for a relative ground truth)."""
    mine = ours(metrics)
    rows = headline_rows(mine)
    if not rows:
        return []
    head = rows[0]
    value = head.value(mine)
    out = []
    for name, block in guesses(metrics).items():
        theirs = head.value(block)
        if value is None or theirs is None:
            continue
        beaten = value > theirs if head.higher_is_better else value < theirs
        if beaten:
            continue
        label, idea = GUESS_LABELS[name]
        how = "ranks pixels no better than" if head.ranking else "is no more accurate than"
        the = "" if label.startswith("your ") else "the "
        out.append(
            f"On this case our depth {how} {the}{label} ({idea}): {head.name} {value:.3g} "
            f"for ours against {theirs:.3g} for the guess ({head.how})."
        )
    return out


@dataclass(frozen=True)
class ComparisonRow:
    label: str
    arrow: str
    values: list[float | None]  # ours, then each guess


@dataclass(frozen=True)
class Comparison:
    """The table ours | radial | brightness on the headline scores, and what it says."""

    names: list[str]  # the columns: ours, then the guesses
    ideas: str  # what each guess assumes
    rows: list[ComparisonRow]
    verdicts: list[str]  # a sentence per guess ours does not beat
    beats_all: str  # the headline row's label when ours beats every guess, else ""


def comparison(metrics: DepthMetrics) -> Comparison | None:
    """Ours beside each guess; None without guesses or scores."""
    mine = ours(metrics)
    rows, found = headline_rows(mine), guesses(metrics)
    if not rows or not found:
        return None
    table = [
        ComparisonRow(
            row.label,
            "↑" if row.higher_is_better else "↓",
            [row.value(mine), *(row.value(b) for b in found.values())],
        )
        for row in rows
    ]
    said = verdicts(metrics)
    compared = rows[0].value(mine) is not None and all(
        rows[0].value(b) is not None for b in found.values()
    )
    return Comparison(
        names=["ours", *(GUESS_LABELS[n][0] for n in found)],
        ideas="; ".join(f"{GUESS_LABELS[n][0]}: {GUESS_LABELS[n][1]}" for n in found),
        rows=table,
        verdicts=said,
        beats_all=rows[0].label if compared and not said else "",
    )
