"""The input frames: the contact sheet of the kept frames and the ingest stage's figures."""

from __future__ import annotations

from endopipe.stages.ingest.summary import IngestSummary
from endopipe.stages.poses.verdict import ranges
from endopipe.stages.report.images import file_image_uri
from endopipe.stages.report.kit import render
from endopipe.stages.report.load import CaseData
from endopipe.stages.report.sections.common import ReportInfo


def section_input(data: CaseData, info: ReportInfo) -> str | None:
    ing = data.ingest_summary
    sheet = None
    if data.ingest is not None:
        path = data.ingest.contact_sheet_path
        sheet = file_image_uri(path, 1100, "jpg", data.cfg.jpeg_quality)
    if sheet is None and ing is None:
        return None
    return render("sections/input.html.j2", sheet=sheet, ing=ing, stereo=stereo_line(ing))


def stereo_line(ing: IngestSummary | None) -> str | None:
    """Which frames had a right view matched (or came with metric depth), and how much of each
    the stereo depth covers (None without stereo)."""
    if ing is None or ing.stereo is None or not ing.stereo_coverage:
        return None
    matched = [i for i, c in enumerate(ing.stereo_coverage) if c is not None]
    shares = [c for c in ing.stereo_coverage if c is not None]
    if not shares:
        return f"{ing.stereo}: no frame had a right view"
    rig = bool(ing.stereo_baseline_mm)  # else the data set's own metric depth maps
    line = (
        f"{len(matched)} of {len(ing.stereo_coverage)} kept frames (positions "
        f"{ranges(matched)}) {'matched' if rig else 'with depth'}, covering "
        f"{min(shares):.0%}-{max(shares):.0%} of the view (mean {sum(shares) / len(shares):.0%})"
    )
    if not rig:
        return f"{line}; depth maps from {ing.stereo}"
    return f"{line}; right views from {ing.stereo}, baseline {ing.stereo_baseline_mm:.2f} mm"
