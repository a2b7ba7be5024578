"""Depth scores side by side, one column per protocol: the table of the depth and NeRF sections,
and the per-frame series of the depth stage's metrics.json."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from endopipe.stages.metrics.scores import DepthScores
from endopipe.stages.report.sections.common import number

#: Depth scores in display order: (DepthScores field, label, higher is better).
DEPTH_METRICS = (
    ("abs_rel", "AbsRel", False),
    ("sq_rel", "SqRel", False),
    ("rmse", "RMSE", False),
    ("rmse_log", "RMSE log", False),
    ("delta1", "δ < 1.25", True),
    ("delta2", "δ < 1.25²", True),
    ("delta3", "δ < 1.25³", True),
    ("spearman", "Spearman ρ", True),
    ("coverage", "Coverage", True),
)
#: A renamed score must fail here, at import, not leave a table row out.
assert {key for key, _, _ in DEPTH_METRICS} <= set(DepthScores.model_fields)

#: The protocols in display order: (metrics.json block, label).
DEPTH_PROTOCOLS = (
    ("median_scaled", "per-frame median scaling"),
    ("sequence_scaled", "one scale for the sequence"),
    ("affine_invariant", "scale and shift fitted per frame (relative ground truth)"),
)


@dataclass(frozen=True)
class ScoreRow:
    label: str
    arrow: str  # ↑ higher is better, ↓ lower; "" for a score of unknown direction
    unit: str
    values: list[Any]  # one per protocol; None: that protocol has no such score


@dataclass(frozen=True)
class ScoreTable:
    """Protocols as columns, scores as rows; empty when no protocol block was computed."""

    protocols: list[str]
    rows: list[ScoreRow]


def score_table(
    median_scaled: DepthScores | None,
    sequence_scaled: DepthScores | None,
    affine_invariant: DepthScores | None = None,
    units: str = "",
) -> ScoreTable:
    """The blocks that were computed side by side; a score some block lacks shows '—'. Scores
    DEPTH_METRICS does not name (e.g. the sequence's scale) follow under their own name."""
    given = (median_scaled, sequence_scaled, affine_invariant)
    blocks = [
        (label, block.model_dump(exclude_none=True))
        for (_, label), block in zip(DEPTH_PROTOCOLS, given, strict=True)
        if block is not None
    ]
    rows = [
        ScoreRow(
            label,
            "↑" if higher else "↓",
            units if key == "rmse" else "",
            [b.get(key) for _, b in blocks],
        )
        for key, label, higher in DEPTH_METRICS
        if any(key in b for _, b in blocks)
    ]
    known = {key for key, _, _ in DEPTH_METRICS}
    extra = sorted(
        {k for _, b in blocks for k, v in b.items() if k not in known and number(v) is not None}
    )
    rows += [ScoreRow(key, "", "", [b.get(key) for _, b in blocks]) for key in extra]
    return ScoreTable([label for label, _ in blocks], rows)


def per_frame_series(per_frame: Any, metric: str = "abs_rel") -> dict[str, tuple[list, list]]:
    """`metric` per frame, by protocol, from metrics.json's per_frame list: entries carry
    "index" and a block per protocol (or, for a relative ground truth, the metrics flat)."""
    out: dict[str, tuple[list, list]] = {}
    if not isinstance(per_frame, list):
        return out
    frames = [f for f in per_frame if isinstance(f, dict)]
    for proto, label in DEPTH_PROTOCOLS:
        pts = [
            (f.get("index", i), f[proto][metric])
            for i, f in enumerate(frames)
            if isinstance(f.get(proto), dict) and f[proto].get(metric) is not None
        ]
        if pts:
            out[label] = ([p[0] for p in pts], [p[1] for p in pts])
    if not out:
        pts = [
            (f.get("index", i), f[metric])
            for i, f in enumerate(frames)
            if f.get(metric) is not None
        ]
        if pts:
            out["per frame"] = ([p[0] for p in pts], [p[1] for p in pts])
    return out
