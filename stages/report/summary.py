"""The report stage's summary, one model on both sides: the stage writes it into its manifest,
`ReportView.summary` reads it back, and report, bench and batch read its fields by name."""

from __future__ import annotations

from endopipe.pipeline.stage import Summary


class ReportSummary(Summary):
    size_mb: float
    gt_kind: str
    mesh_viewer: str
    sections: dict[str, bool]  # each section: shown (True) or "not available" (False)
