"""`endopipe bench --profile`: where the time goes. Each case runs every stage from nothing
(fresh case folder, nothing cached) and each stage's wall time, CPU time (every thread) and
peak memory are read back from its manifest, beside what the stage says of its own speed
(NeRF steps reached, depth ms per map, the poses' step timings) and the case's accuracy, so a
speed change is seen with what it costs.

Cases: bench cases by name (`--case`, default the bench colon) and real inputs (`--input PATH`,
e.g. the C3VD preview), run with the default configuration plus `--set`.
"""

from __future__ import annotations

import csv
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from endopipe.pipeline.runner import Pipeline
from endopipe.stages.depth.summary import DepthSummary
from endopipe.stages.mesh.summary import MeshSummary
from endopipe.stages.nerf.summary import NerfSummary
from endopipe.stages.poses.summary import PosesSummary

PROFILE_COLUMNS = ("case", "stage", "wall_s", "cpu_s", "threads_busy", "peak_mb", "note")


class ProfileRow(BaseModel):
    """One stage of one case (stage "all": the case's totals and its accuracy)."""

    case: str
    stage: str
    wall_s: float | None = None
    cpu_s: float | None = None
    peak_mb: float | None = None
    note: str = ""

    @property
    def threads_busy(self) -> float | None:
        """CPU seconds per wall second: how many cores the stage kept busy on average."""
        if self.wall_s and self.cpu_s is not None:
            return self.cpu_s / self.wall_s
        return None


def profile_case(
    pipe: Pipeline,
    source: Path,
    case_dir: Path,
    configs: dict,
    prepare: Callable[[Path, Path, str], Path],
    console: Any,
) -> list[ProfileRow]:
    """Run `source` through every stage from nothing into `case_dir`; one row per stage, then
    the totals."""
    shutil.rmtree(case_dir, ignore_errors=True)
    case_dir = prepare(source, case_dir.parent, case_dir.name)
    t0 = time.perf_counter()
    pipe.run(case_dir, configs, force=True, console=console, quiet=False)
    return profile_rows(pipe, case_dir, time.perf_counter() - t0)


def profile_rows(pipe: Pipeline, case_dir: Path, elapsed: float) -> list[ProfileRow]:
    """A finished case's stages as rows (from their manifests and summaries), then the totals:
    `elapsed` wall seconds, every stage's CPU, the highest peak, the accuracy."""
    rows = []
    for stage in pipe.stages:
        m = pipe.manifest(case_dir, stage.name)
        if m is None:
            continue
        rows.append(
            ProfileRow(
                case=case_dir.name,
                stage=stage.name,
                wall_s=m.wall_s,
                cpu_s=m.cpu_s,
                peak_mb=m.peak_rss_mb,
                note=stage_note(pipe.view(case_dir, stage.name).summary),
            )
        )
    rows.append(
        ProfileRow(
            case=case_dir.name,
            stage="all",
            wall_s=elapsed,
            cpu_s=sum(r.cpu_s or 0.0 for r in rows),
            peak_mb=max((r.peak_mb or 0.0 for r in rows), default=None),
            note=accuracy_note(pipe, case_dir),
        )
    )
    return rows


def stage_note(summary: Any) -> str:
    """What a stage says of its own speed, in a few words."""
    if isinstance(summary, PosesSummary):
        steps = ", ".join(f"{k.removesuffix('_s')} {v:.0f} s" for k, v in summary.timings.items())
        return f"{summary.mapper or summary.source}; {steps}" if steps else summary.source
    if isinstance(summary, NerfSummary):
        return f"{summary.steps} steps, {summary.rays_per_s:.0f} rays/s, {summary.device}"
    if isinstance(summary, DepthSummary):
        s = summary
        return f"{s.ms_per_frame:.0f} ms per map ({s.renderer}), bake {s.bake_s:.0f} s"
    if isinstance(summary, MeshSummary):
        return f"{summary.method}, {summary.faces} faces"
    return ""


def accuracy_note(pipe: Pipeline, case_dir: Path) -> str:
    """The case's headline accuracy: Spearman / SSI-AbsRel / coverage against a relative ground
    truth, else AbsRel / coverage and the mesh's Chamfer; empty without ground truth."""
    if pipe.manifest(case_dir, "depth") is None:
        return ""
    depth: DepthSummary = pipe.view(case_dir, "depth").summary
    parts = []
    a = depth.affine_invariant
    if a is not None and a.spearman is not None and a.abs_rel is not None:
        parts.append(f"Spearman {a.spearman:.3f}, SSI-AbsRel {a.abs_rel:.3f}")
    elif depth.median_scaled is not None and depth.median_scaled.abs_rel is not None:
        parts.append(f"AbsRel {depth.median_scaled.abs_rel:.4f}")
    if depth.coverage is not None:
        parts.append(f"coverage {depth.coverage:.3f}")
    if pipe.manifest(case_dir, "mesh") is not None:
        mesh: MeshSummary = pipe.view(case_dir, "mesh").summary
        if mesh.chamfer_pct_radius is not None:
            parts.append(f"Chamfer {mesh.chamfer_pct_radius:.2f}% r")
    if depth.unknown_share is not None:
        parts.append(f"{100 * depth.unknown_share:.1f}% unknown")
    return ", ".join(parts)


def _cell(value: float | None, digits: int) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def profile_table(rows: list[ProfileRow]) -> str:
    """Markdown: one line per case and stage."""
    lines = [
        "| case | stage | wall s | CPU s | cores busy | peak MB | note |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        name = f"**{r.stage}**" if r.stage == "all" else r.stage
        lines.append(
            f"| {r.case} | {name} | {_cell(r.wall_s, 1)} | {_cell(r.cpu_s, 1)} | "
            f"{_cell(r.threads_busy, 2)} | {_cell(r.peak_mb, 0)} | {r.note} |"
        )
    return "\n".join(lines)


def write_profile_csv(path: Path, rows: list[ProfileRow]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(PROFILE_COLUMNS)
        for r in rows:
            writer.writerow([r.case, r.stage, r.wall_s, r.cpu_s, r.threads_busy, r.peak_mb, r.note])
