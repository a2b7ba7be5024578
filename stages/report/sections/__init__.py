"""The page's sections, one module each; SECTIONS is their order on the page.

A section reads the case (`CaseData`: views, typed summaries, metrics files) and returns its
HTML, rendered from its template in templates/sections/, or None when it has nothing at all
to show (the page then says "not available").
"""

from __future__ import annotations

from endopipe.stages.report.sections.common import ReportInfo, Section
from endopipe.stages.report.sections.depth import section_depth
from endopipe.stages.report.sections.ingest import section_input
from endopipe.stages.report.sections.mesh import section_mesh
from endopipe.stages.report.sections.nerf import section_nerf
from endopipe.stages.report.sections.poses import section_poses
from endopipe.stages.report.sections.runs import section_runs
from endopipe.stages.report.sections.scores import per_frame_series
from endopipe.stages.report.sections.summary import section_summary
from endopipe.stages.report.sections.timings import section_stages

#: (anchor, title, renderer), in page order.
SECTIONS: tuple[tuple[str, str, Section], ...] = (
    ("summary", "Summary", section_summary),
    ("stages", "Stages: time and memory", section_stages),
    ("input", "Input frames", section_input),
    ("poses", "Camera trajectory and centre line", section_poses),
    ("nerf", "NeRF training", section_nerf),
    ("depth", "Depth", section_depth),
    ("mesh", "Mesh", section_mesh),
    ("runs", "Runs and environment", section_runs),
)

__all__ = [
    "SECTIONS",
    "ReportInfo",
    "Section",
    "per_frame_series",
    "section_depth",
    "section_input",
    "section_mesh",
    "section_nerf",
    "section_poses",
    "section_runs",
    "section_stages",
    "section_summary",
]
