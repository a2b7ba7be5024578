"""`07_report/` (docs/formats.md): the only reader of the report stage's folder.

Commands (batch, export) ask here where a case's page is, instead of spelling the file name.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from endopipe.pipeline.stage import read_summary
from endopipe.stages.report.summary import ReportSummary

#: The one file the report stage writes.
PAGE = "report.html"


@dataclass(frozen=True)
class ReportView:
    """The report stage's published folder."""

    folder: Path

    @property
    def page(self) -> Path:
        """The self-contained HTML page (it may not exist: check `.is_file()`)."""
        return self.folder / PAGE

    @property
    def summary(self) -> ReportSummary:
        """The stage's summary in its manifest (SummaryMismatch when written with other fields)."""
        return read_summary(self.folder, ReportSummary)
