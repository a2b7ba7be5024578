"""report: one self-contained HTML page per case (07_report/report.html).

Everything is inlined, so the page opens offline and can be mailed as one file: images are base64
PNG / JPEG data URIs, the CSS is inline, the depth preview video (when small enough) is an mp4
data URI, and the 3D mesh viewer is trimesh's three.js page (trimesh bundles three.js inside
its package, no CDN) placed in an `<iframe srcdoc>`. Static renderings of the mesh are
always included as well, for print and for browsers without WebGL.

What the page shows: the case (input, frames, registered ratio, metric or not, ground-truth
kind), every stage's wall time and peak memory (from each stage folder's manifest.json), the
camera trajectory and the centre line, the poses' verdict (ok / doubtful and why, frame by
frame; a doubtful one also on the summary), the NeRF's loss curves, depth previews with error maps,
the metric tables (depth under both protocols, mesh, poses, PSNR / SSIM) and the recent runs.
Any missing artefact (no ground truth, no mesh metrics, a stage folder absent) is shown as
"not available" with the reason; a section never takes the page down. A stage summary that
does not match its stage's model (a folder written by another version) is named, with the
`--from` to re-run, at the top of each section that reads it, and that section counts as not
available: a renamed field never shows as a blank value.

Modules: load.py (the stages' views, typed summaries, manifests, run records), sections/ (one
module per section, with its template in templates/sections/), figures.py (plots), mesh3d.py
(the mesh on the page), kit.py + templates/ (all the HTML), render.py (the page).
"""

from __future__ import annotations

from endopipe.pipeline.stage import Stage, StageContext
from endopipe.stages.report.config import ReportConfig
from endopipe.stages.report.render import render_report
from endopipe.stages.report.summary import ReportSummary
from endopipe.stages.report.view import PAGE, ReportView


class Report(Stage):
    """A self-contained HTML report: summary, timings, plots, depth previews, metrics, 3D mesh."""

    name = "report"
    needs = ("ingest", "poses", "centerline", "nerf", "depth", "mesh")
    version = 1
    Config = ReportConfig
    Summary = ReportSummary
    View = ReportView

    def run(self, ctx: StageContext[ReportConfig]) -> ReportSummary:
        cfg = ctx.config
        folders = {name: ctx.input_dir(name) for name in self.needs}
        page, info = render_report(
            ctx.case_dir, folders, cfg, open_view=lambda name, _folder: ctx.input_by_name(name)
        )
        path = ctx.out / PAGE
        path.write_text(page, encoding="utf-8")
        size_mb = path.stat().st_size / 2**20
        missing = [k for k, ok in info.sections.items() if not ok]
        ctx.log(
            f"report.html: {size_mb:.1f} MB, mesh viewer: {info.mesh_viewer}"
            + (f"; not available: {', '.join(missing)}" if missing else "")
        )
        return ReportSummary(
            size_mb=round(size_mb, 3),
            gt_kind=info.gt_kind,
            mesh_viewer=info.mesh_viewer,
            sections=info.sections,
        )
