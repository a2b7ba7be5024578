"""batch.html: the batch's table as one self-contained page, linked to each case's report."""

from __future__ import annotations

import html
import os
import time
from collections.abc import Sequence
from pathlib import Path

from endopipe.commands.batch.table import (
    POSE_COLUMNS,
    column_stats,
    format_cell,
    metric_columns,
    row_values,
    table_columns,
)
from endopipe.jobs.rows import CaseRow

_CSS = """
body{font:14px system-ui,sans-serif;margin:24px;color:#222}
table{border-collapse:collapse;font-size:13px}
th,td{border:1px solid #ccc;padding:3px 7px;text-align:right;white-space:nowrap}
th{background:#f0f0f0;position:sticky;top:0}
td.t{text-align:left}
td.reason{text-align:left;white-space:normal;max-width:420px}
tr.failed td{background:#fdecea}
tr.stat td{background:#eef4fb;font-weight:600}
.ok{color:#1a7f37}.failed{color:#b42318}.pseudo{color:#9a6700}
.doubtful{color:#b42318;font-weight:600}.muted{color:#777}
"""


def write_html(rows: Sequence[CaseRow], path: Path, title: str = "endopipe batch") -> Path:
    """A self-contained table: one row per case (linked to its report), then mean and median."""
    metrics = metric_columns(rows)
    columns = table_columns(rows)
    stats = column_stats(rows)
    text_cols = {"case", "status", "reader", "gt_kind", "stages_ran", "stages_cached"}
    text_cols |= {"failed_stage", *POSE_COLUMNS[:-1]}
    esc = html.escape
    out = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>{esc(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{esc(title)}</h1>",
    ]
    n_ok = sum(r.status == "ok" for r in rows)
    n_doubtful = sum(r.pose_verdict == "doubtful" for r in rows)
    doubtful = f"; <span class='doubtful'>{n_doubtful} with doubtful poses</span>"
    out.append(
        f"<p>{len(rows)} case(s): {n_ok} ok, {len(rows) - n_ok} failed"
        f"{doubtful if n_doubtful else ''}. "
        f"Written {esc(time.strftime('%Y-%m-%d %H:%M:%S'))}. "
        "<span class='pseudo'>gt_kind pseudo</span>: the ground truth is derived (e.g. Hamlyn's "
        "stereo depth), not measured; treat its metrics as indicative. "
        "<span class='doubtful'>pose_verdict doubtful</span>: the poses failed a check without "
        "ground truth (pose_reasons says which); everything after them inherits it.</p>"
    )
    out.append("<table><thead><tr>")
    out += [f"<th>{esc(c)}</th>" for c in columns]
    out.append("</tr></thead><tbody>")
    for row in rows:
        values = row_values(row, metrics)
        out.append(f"<tr class='{esc(row.status)}'>")
        for c in columns:
            cell = esc(format_cell(values[c]))
            if c == "case" and row.report:
                rel = os.path.relpath(Path(path).parent / row.report, Path(path).parent)
                cell = f"<a href='{esc(Path(rel).as_posix())}'>{cell}</a>"
            elif c == "status":
                cell = f"<span class='{esc(row.status)}'>{cell}</span>"
            elif c == "gt_kind" and row.gt_kind == "pseudo":
                cell = f"<span class='pseudo'>{cell}</span>"
            elif c == "pose_verdict" and row.pose_verdict:
                kind = {"ok": "ok", "doubtful": "doubtful"}.get(row.pose_verdict, "muted")
                cell = f"<span class='{kind}'>{cell}</span>"
            klass = "reason" if c in ("reason", "pose_reasons") else ("t" if c in text_cols else "")
            out.append(f"<td class='{klass}'>{cell}</td>" if klass else f"<td>{cell}</td>")
        out.append("</tr>")
    out.append("</tbody><tfoot>")
    for label, i in (("mean", 0), ("median", 1)):
        out.append(f"<tr class='stat'><td class='t'>{label}</td>")
        for c in columns[1:]:
            s = stats.get(c)
            out.append(f"<td>{format_cell(s[i])}</td>" if s else "<td></td>")
        out.append("</tr>")
    out.append("</tfoot></table></body></html>\n")
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text("".join(out))
    tmp.replace(path)
    return path
