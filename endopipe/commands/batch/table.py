"""batch.csv: one row per case, fixed columns then every stage's numeric summary."""

from __future__ import annotations

import csv
import statistics
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from endopipe.jobs.rows import CaseRow

FIXED_COLUMNS = (
    "case",
    "status",
    "reader",
    "gt_kind",
    "stages_ran",
    "stages_cached",
    "failed_stage",
    "reason",
    "wall_s",
    "this_batch_s",
    "compute_s",
    "peak_rss_mb",
)
NUMERIC_FIXED = ("wall_s", "this_batch_s", "compute_s", "peak_rss_mb", "doubtful_frames")
#: The poses' verdict, shown just before the poses stage's own numbers (`poses.*`).
POSE_COLUMNS = ("pose_verdict", "pose_reasons", "mapper", "doubtful_frames")


def metric_columns(rows: Sequence[CaseRow]) -> list[str]:
    cols: dict[str, None] = {}
    for row in rows:
        cols.update(dict.fromkeys(row.metrics))
    return list(cols)


def table_columns(rows: Sequence[CaseRow]) -> list[str]:
    """The fixed columns, then each stage's numbers; the pose verdict sits before the poses
    stage's numbers (or after the fixed columns when there are none)."""
    metrics = metric_columns(rows)
    at = next((k for k, m in enumerate(metrics) if m.startswith("poses.")), 0)
    return [*FIXED_COLUMNS, *metrics[:at], *POSE_COLUMNS, *metrics[at:]]


def format_cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, list):
        return "+".join(value)
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def row_values(row: CaseRow, metrics: Sequence[str]) -> dict[str, Any]:
    data = row.model_dump()
    out = {c: data[c] for c in (*FIXED_COLUMNS, *POSE_COLUMNS)}
    out.update({m: row.metrics.get(m) for m in metrics})
    out["report"] = row.report
    out["input"] = row.input
    out["host"] = row.host
    return out


def write_csv(rows: Sequence[CaseRow], path: Path) -> Path:
    metrics = metric_columns(rows)
    columns = [*table_columns(rows), "report", "input", "host"]
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        for row in rows:
            values = row_values(row, metrics)
            writer.writerow([format_cell(values[c]) for c in columns])
    tmp.replace(path)
    return path


def column_stats(rows: Sequence[CaseRow]) -> dict[str, tuple[float, float, int]]:
    """(mean, median, count) of every numeric column over the cases that have it."""
    out = {}
    for col in [*NUMERIC_FIXED, *metric_columns(rows)]:
        values = []
        for row in rows:
            v = getattr(row, col) if col in NUMERIC_FIXED else row.metrics.get(col)
            if v is not None and (col not in NUMERIC_FIXED or row.status == "ok"):
                values.append(float(v))
        if values:
            out[col] = (statistics.fmean(values), statistics.median(values), len(values))
    return out
