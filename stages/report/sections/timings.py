"""Every stage's wall time, peak memory and outputs, from its folder's manifest, with the
config and summary it was run with."""

from __future__ import annotations

import datetime as dt
import json
from typing import Any

from endopipe.stages.report.kit import duration, render
from endopipe.stages.report.load import STAGES, CaseData
from endopipe.stages.report.sections.common import ReportInfo


def section_stages(data: CaseData, info: ReportInfo) -> str | None:
    walls = [m.wall_s for m in data.manifests.values() if m is not None]
    if not walls and not any(data.folder(s) for s in STAGES):
        return None
    longest = max(walls) if walls else 1.0
    rows: list[dict[str, Any]] = []
    for stage in STAGES:
        m = data.manifests.get(stage)
        folder = data.folder(stage)
        row: dict[str, Any] = {
            "stage": stage,
            "folder": folder.name if folder is not None else None,
            "manifest": m is not None,
        }
        if m is not None:
            row.update(
                wall=duration(m.wall_s),
                share=100.0 * m.wall_s / longest if longest > 0 else 0.0,
                peak_mb=m.peak_rss_mb,
                files=len(m.files),
                size_mb=sum(f.size for f in m.files.values()) / 2**20,
                version=m.version,
                key=m.key[:8],
                finished=dt.datetime.fromtimestamp(m.finished).strftime("%Y-%m-%d %H:%M:%S"),
            )
        rows.append(row)
    peak = max((m.peak_rss_mb for m in data.manifests.values() if m is not None), default=0.0)
    # the manifest as written, so a summary that no longer validates can still be read here
    details = [
        (
            f"{stage}: config and summary",
            json.dumps({"config": m.config, "summary": m.summary}, indent=2, default=str),
        )
        for stage in STAGES
        if (m := data.manifests.get(stage)) is not None
    ]
    return render(
        "sections/stages.html.j2",
        rows=rows,
        total_wall=duration(sum(walls)),
        peak_mb=peak,
        details=details,
    )
