"""NeRF training: the loss curves, the held-out renderings, the run's figures and the rendered
depth of the held-out frames."""

from __future__ import annotations

from endopipe.stages.nerf.summary import CHANNELS, ColourRefit
from endopipe.stages.report.images import file_image_uri
from endopipe.stages.report.kit import render
from endopipe.stages.report.load import CaseData
from endopipe.stages.report.sections.common import ReportInfo
from endopipe.stages.report.sections.scores import score_table

#: The fit's word (nerf/fit.py) and its badge's colour.
FIT_BADGE = {
    "learned": ("learned its images", "ok"),
    "learned, not held out": ("learned, not held out", "warn"),
    "not learned": ("did not learn its images", "bad"),
}


def section_nerf(data: CaseData, info: ReportInfo) -> str | None:
    nerf, s = data.nerf, data.nerf_summary
    loss = held = pairs = None
    if nerf is not None:
        loss = file_image_uri(nerf.loss_plot_path, 1100)
        held = file_image_uri(nerf.heldout_plot_path, 1100, "jpg", data.cfg.jpeg_quality)
        pairs = file_image_uri(nerf.heldout_pairs_path, 1100, "jpg", data.cfg.jpeg_quality)
    if loss is None and held is None and s is None:
        return None
    nm = data.nerf_metrics
    # metrics.json's PSNR first, then the summary's (the same number, when both exist)
    psnr = nm.psnr if nm is not None else None
    if psnr is None and s is not None:
        psnr = s.heldout_psnr
    depth = s.depth if s is not None else None
    return render(
        "sections/nerf.html.j2",
        loss=loss,
        held=held,
        pairs=pairs,
        fit=FIT_BADGE.get(nm.fit or "") if nm is not None else None,
        nm=nm,
        s=s,
        render_rgb_ms=nm.render_rgb_ms if nm is not None else None,
        psnr=psnr,
        show_psnr=psnr is not None,
        refit=refit_line(s.colour_refit) if s is not None else None,
        depth=score_table(
            depth.median_scaled, depth.sequence_scaled, depth.affine_invariant, units=data.units
        )
        if depth is not None
        else None,
    )


def refit_line(refit: ColourRefit | None) -> str | None:
    """What the albedo's refit did, in one line (nerf/colour_phase.py); None when it did not run."""
    if refit is None or not refit.steps:
        return None
    c = max(range(3), key=refit.ceiling.__getitem__)
    return (
        f"the {CHANNELS[c]} channel's albedo sat at its ceiling on "
        f"{refit.ceiling[c]:.0%} of the training rays (its brightness all shading, the cue the "
        f"depth rests on): {refit.steps} steps then fitted the albedo alone with the geometry "
        f"fixed and the light x{refit.light_factor or 0:.2f}, so the depth is the geometry's "
        "as trained and the renders are the images'"
    )
