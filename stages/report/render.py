"""The page: every section rendered in turn into the Jinja2 template (templates/report.html.j2).

A section that fails shows "not available" with the reason; the page is always produced.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from endopipe.stages.report import sections as sec
from endopipe.stages.report.config import ReportConfig
from endopipe.stages.report.kit import not_available, one_line, page
from endopipe.stages.report.load import CaseData, ViewOpener, load_case, stage_view


@dataclass
class ReportInfo:
    """What the page ended up holding (the stage's summary)."""

    gt_kind: str = "none"
    mesh_viewer: str = "none"
    sections: dict[str, bool] = field(default_factory=dict)


Section = Callable[[CaseData, ReportInfo], "str | None"]

#: (anchor, title, renderer), in page order.
SECTIONS: tuple[tuple[str, str, Section], ...] = (
    ("summary", "Summary", sec.section_summary),
    ("stages", "Stages: time and memory", sec.section_stages),
    ("input", "Input frames", sec.section_input),
    ("poses", "Camera trajectory and centre line", sec.section_poses),
    ("nerf", "NeRF training", sec.section_nerf),
    ("depth", "Depth", sec.section_depth),
    ("mesh", "Mesh", sec.section_mesh),
    ("runs", "Runs and environment", sec.section_runs),
)


def build_report(
    case_dir: Path,
    stage_folders: dict[str, Path],
    config: ReportConfig | None = None,
    open_view: ViewOpener = stage_view,
) -> str:
    """The report's HTML for a case whose stage folders are `stage_folders` (name -> folder)."""
    return render_report(case_dir, stage_folders, config or ReportConfig(), open_view)[0]


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
    body = []
    for key, title, fn in SECTIONS:
        try:
            content = fn(data, info)
        except Exception as e:  # noqa: BLE001 - a broken artefact must not take the page down
            info.sections[key] = False
            content = not_available(f"this section failed to render: {one_line(e)}")
        else:
            info.sections.setdefault(key, content is not None)
            if content is None:
                content = not_available("no artefacts for this section")
        body.append({"key": key, "title": title, "body": content})
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
