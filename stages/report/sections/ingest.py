"""The input frames: the contact sheet of the kept frames and the ingest stage's figures."""

from __future__ import annotations

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
    return render("sections/input.html.j2", sheet=sheet, ing=ing)
