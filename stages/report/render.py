"""The page: every section rendered in turn into the Jinja2 template (templates/report.html.j2).

A section that fails, or that read a stage summary which does not validate, shows "not
available" with the reason and is marked so in the report's summary; the page is always
produced.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

from markupsafe import Markup

from endopipe.stages.report.config import ReportConfig
from endopipe.stages.report.kit import not_available, one_line, page
from endopipe.stages.report.load import STAGES, CaseData, ViewOpener, load_case, stage_view
from endopipe.stages.report.sections import SECTIONS, ReportInfo, Section

__all__ = ["ReportInfo", "build_report", "render_report"]


def build_report(
    case_dir: Path,
    stage_folders: dict[str, Path],
    config: ReportConfig | None = None,
    open_view: ViewOpener = stage_view,
) -> str:
    """The report's HTML for a case whose stage folders are `stage_folders` (name -> folder)."""
    return render_report(case_dir, stage_folders, config or ReportConfig(), open_view)[0]


def render_section(data: CaseData, info: ReportInfo, key: str, fn: Section) -> str:
    """One section's HTML; records in `info.sections` whether it is available. A summary it
    asked for that did not validate is named at its top: its figures are not shown blank."""
    data.summaries_read.clear()
    try:
        content = fn(data, info)
    except Exception as e:  # noqa: BLE001 - a broken artefact must not take the page down
        info.sections[key] = False
        content = not_available(f"this section failed to render: {one_line(e)}")
    else:
        info.sections.setdefault(key, content is not None)
        if content is None:
            content = not_available("no artefacts for this section")
    unreadable = [s for s in STAGES if s in data.summaries_read and s in data.summary_errors]
    if unreadable:
        info.sections[key] = False
        notes = "".join(not_available(data.summary_errors[s]) for s in unreadable)
        content = Markup(notes) + Markup(content)
    return str(content)


def render_report(
    case_dir: Path,
    stage_folders: dict[str, Path],
    cfg: ReportConfig,
    open_view: ViewOpener = stage_view,
) -> tuple[str, ReportInfo]:
    data = load_case(case_dir, stage_folders, cfg, open_view)
    try:
        info = ReportInfo(gt_kind=data.gt_kind())
    except Exception:  # noqa: BLE001 - an unreadable truth is no truth
        info = ReportInfo()
    body = [
        {"key": key, "title": title, "body": render_section(data, info, key, fn)}
        for key, title, fn in SECTIONS
    ]
    name = data.case.name if data.case else data.case_dir.name
    html = page(
        title=cfg.title or f"endopipe report: {name}",
        subtitle=data.case.input if data.case else str(data.case_dir),
        generated=dt.datetime.now().strftime("%Y-%m-%d %H:%M"),
        version=_endopipe_version(),
        sections=body,
    )
    return html, info


def _endopipe_version() -> str:
    try:
        import importlib.metadata

        return importlib.metadata.version("endopipe")
    except Exception:  # noqa: BLE001
        return "dev"
