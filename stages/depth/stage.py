"""depth: a z-depth map per registered frame from the trained field, evaluated when GT exists.

config.py holds the settings, evaluate.py the comparison with the ground truth, preview.py the
colour and error maps of preview.mp4, view.py the only reader of 05_depth.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np

from endopipe.pipeline.stage import Stage, StageContext
from endopipe.stages.camera import Camera, lens_valid_mask
from endopipe.stages.centerline.view import CenterlineView
from endopipe.stages.depth.anchor import Anchor, Anchored
from endopipe.stages.depth.config import DepthConfig
from endopipe.stages.depth.evaluate import (
    evaluate,
    ground_truth_depths,
    prior_maps,
    scores_by_support,
    shading_maps,
    stereo_maps,
)
from endopipe.stages.depth.metrics_file import DepthMetrics
from endopipe.stages.depth.preview import write_preview
from endopipe.stages.depth.renderer import READ_OUT_WHY, FieldSight, field_depth, stereo_sight
from endopipe.stages.depth.summary import DepthSummary
from endopipe.stages.depth.support import write_support
from endopipe.stages.depth.view import DEPTH_DIR, OPACITY_DIR, PREVIEW_FILE, DepthView, frame_file
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.nerf.shading_depth import only_shading_places_depth
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import PosesView

__all__ = ["Depth", "DepthConfig", "DepthSummary", "DepthView"]

PNG_MAX = 65535


class Depth(Stage):
    """Render every registered frame's depth (z, world units) and opacity; evaluate against GT."""

    name = "depth"
    needs = ("ingest", "poses", "centerline", "nerf")
    # 17: no iso-surface in a free scene, its own spread limit; 16: a stereo pair alone: the
    # rig's depth; 15: depth held to the stereo or the SfM
    # points; 14: a volume-rendered ray's depth is its weights' median where no measured depth
    # trained the field; 13: tools left out of the scores, depth from shading scored; 12: says
    # when the truth also supervised; 11: the depth prior scored; 10: stereo
    version = 17
    Config = DepthConfig
    Summary = DepthSummary
    View = DepthView

    def run(self, ctx: StageContext[DepthConfig]) -> DepthSummary:
        cfg = ctx.config
        ingest = ctx.input(IngestView)
        poses = ctx.input(PosesView)
        centerline = ctx.input(CenterlineView)
        nerf = ctx.input(NerfView)
        if nerf.trained:
            sight = FieldSight.open(cfg, ingest, poses, centerline, nerf)
            used = "field" if sight.model.field.dynamic else cfg.renderer
        else:
            sight, used = stereo_sight(ingest, poses), "stereo"
            ctx.log(f"no field ({nerf.summary.skipped}): each depth map is the stereo's")
        renderer, k, c2w, bake_s = sight.render, sight.camera, sight.c2w, sight.bake_s
        heldout = set(getattr(sight.model, "meta", {}).get("heldout", []))
        if used not in (cfg.renderer, "stereo"):
            ctx.log("renderer field: a dynamic field renders each frame at its own time")
        if used == "field":
            ctx.log(f"each ray's depth: {READ_OUT_WHY[field_depth(cfg, nerf)]}")
        beyond_lens = unseen_pixels(k, ingest)  # no ray, or outside the scope: no depth
        anchor = Anchor.open(
            cfg.anchor if nerf.trained else "off",
            ingest,
            poses,
            cfg.anchor_sigma_stereo,
            cfg.anchor_sigma_points,
        )
        held: list[Anchored] = []
        for sub in (DEPTH_DIR, OPACITY_DIR):
            (ctx.out / sub).mkdir()
        depths, rgbs, times = {}, {}, []
        lens_px, unknown_px, hazy_px = int((~beyond_lens).sum()), 0, 0
        with (
            ctx.progress("depth", total=len(poses.registered)) as advance,
            torch_threads(1 if used == "baked" else None),
        ):
            for i in poses.registered:
                t0 = time.perf_counter()
                out = renderer(k, c2w[i], i, colour=cfg.colour and i in heldout)
                times.append(time.perf_counter() - t0)
                out["depth"][beyond_lens] = 0.0
                out["opacity"][beyond_lens] = 0.0
                depth, how = anchor.apply(i, out["depth"].astype(np.float32))
                depth[beyond_lens] = 0.0
                if how is not None:
                    held.append(how)
                depths[i] = depth
                unknown_px += int((depths[i][~beyond_lens] <= 0).sum())
                hazy_px += int(out["hazy"][~beyond_lens].sum())
                np.save(ctx.out / DEPTH_DIR / frame_file(i), depths[i])
                np.save(ctx.out / OPACITY_DIR / frame_file(i), out["opacity"].astype(np.float32))
                if "rgb" in out:
                    rgbs[i] = out["rgb"]
                advance(info=f"{1000 * times[-1]:.0f} ms/frame")
        png_scale = write_depth_pngs(ctx.out / DEPTH_DIR, depths)
        measured_share = corrected_share = None
        if held:
            measured_share = float(np.mean([h.measured for h in held]))
            corrected_share = float(np.mean([h.corrected for h in held]))
            ratio = np.median([h.median_ratio for h in held if h.median_ratio is not None])
            ctx.log(
                f"depth held to the {anchor.source} in {len(held)} of {len(depths)} frames: "
                f"{measured_share:.0%} of the depth pixels measured, {corrected_share:.0%} the "
                f"field's corrected to them (measured over the field's depth, median {ratio:.3f})"
            )
        extrapolated = poses.past_fitted_radius(k)
        still = poses.still
        stereo = stereo_maps(ingest, list(depths))
        if still and stereo:
            ctx.log(
                f"depth from a still camera with metric depth: {ingest.stereo_measured_by} "
                "measured it, in millimetres, where its maps cover the frame; elsewhere the field "
                "fills it in"
            )
        elif still:
            ctx.log(
                "depth from one viewpoint (the camera stands still): no pixel was seen from two "
                "places, so depth is relative, from shading, smoothness and the field's fit "
                "over time, and weaker than depth measured by parallax"
            )
        support = write_support(
            ctx.out, cfg, ingest, depths, c2w, k, beyond_lens, extrapolated, still
        )
        gt = ingest.ground_truth_for_scores(ctx.log)
        circular = ingest.truth_supervised(gt)
        if circular is not None:
            ctx.log(
                f"the ground truth's depth ({circular}) also supervised the field: scores "
                "against it say how closely the field follows it, not how right it is"
            )
        gt_depths = ground_truth_depths(gt, ingest, list(depths))
        shading = None
        if gt_depths and only_shading_places_depth(ingest, poses):
            gamma = sight.model.cfg.shading.gamma  # as the field's depth from shading
            shading = shading_maps(ingest, k, sorted(gt_depths), gamma)  # k: the working size
        evaluation = evaluate(
            gt,
            ingest,
            depths,
            gt_depths,
            rgbs,
            (k.cx, k.cy),
            poses.metric,
            (stereo or None) if nerf.trained else None,  # a pair alone: ours is the stereo
            prior_maps(ingest, list(depths)) or None,
            shading,
            nerf.trained and nerf.metrics is not None and nerf.metrics.exposure_fitted,
        )
        if support is not None and gt_depths:
            by = scores_by_support(gt, ingest, depths, gt_depths, support.seen_again_maps)
            evaluation["by_support"] = by or None
        metrics = DepthMetrics.model_validate(evaluation)
        metrics.write(ctx.out)
        if metrics.tool_share_left_out:
            ctx.log(
                f"scores leave out the {metrics.tool_share_left_out:.1%} of the view on tools: "
                "the truth there is the tool, ours the tissue inferred under it"
            )
        if cfg.preview:
            affine = metrics.gt_kind == "relative"
            write_preview(
                ctx.out / PREVIEW_FILE,
                ingest,
                depths,
                gt_depths,
                cfg.preview_fps,
                affine,
                units=poses.file.units,
            )
        ms = 1000 * float(np.median(times[1:] if len(times) > 1 else times))
        pixels = max(lens_px * len(depths), 1)
        ctx.log(
            f"{len(depths)} depth maps, {ms:.0f} ms per frame ({used}; "
            f"baking {bake_s:.1f} s); no depth on {unknown_px / pixels:.1%} of the lens's "
            f"pixels, {hazy_px / pixels:.1%} for a ray spread over no one surface "
            "(depth.max_spread; without a lumen prior depth.free_max_spread)"
        )
        if support is not None and len(depths) > 1:  # one view has no others to agree
            ctx.log(
                f"views: {support.seen_again / pixels:.1%} of the lens's pixels have a depth "
                f"{cfg.seen_again_views} other views agree with, {support.one_view / pixels:.1%} "
                f"one no other view confirms; {support.inferred / pixels:.1%} are inferred "
                f"(under their frame's own mask, or {support.extrapolated / pixels:.1%} past the "
                "radius the estimated lens was fitted within)"
            )
        return DepthSummary(
            frames=len(depths),
            units=poses.file.units,
            png_scale=png_scale,
            ms_per_frame=ms,
            bake_s=bake_s,
            renderer=used,
            gt_kind=metrics.gt_kind,
            median_scaled=metrics.median_scaled,
            sequence_scaled=metrics.sequence_scaled,
            unscaled=metrics.unscaled,
            affine_invariant=metrics.affine_invariant,
            coverage=headline.coverage if (headline := metrics.headline()) else None,
            unknown_share=unknown_px / pixels,
            hazy_share=hazy_px / pixels,
            seen_again_share=support.seen_again / pixels if support else None,
            one_view_share=support.one_view / pixels if support else None,
            inferred_share=support.inferred / pixels if support else None,
            extrapolated_share=support.extrapolated / pixels if support else None,
            baselines=metrics.baselines,
            heldout_psnr=metrics.heldout_psnr,
            heldout_ssim=metrics.heldout_ssim,
            one_viewpoint=still and not stereo,
            truth_supervised=circular,
            anchored_to=anchor.source if held else None,
            measured_share=measured_share,
            corrected_share=corrected_share,
            neighbour_psnr=(metrics.neighbour_average or {}).get("psnr"),
            neighbour_ssim=(metrics.neighbour_average or {}).get("ssim"),
        )


def unseen_pixels(k: Camera, ingest: IngestView) -> np.ndarray:
    """(H, W) bool: the pixels that get no depth whatever the field holds: those the lens model
    gives no ray (poses logs how many) and those outside the scope's field of view (its black
    surround, which a lens that reaches every pixel would otherwise cast into the scene)."""
    unseen = ~lens_valid_mask(k)
    fov = ingest.fov()
    if fov is not None:
        if fov.shape != unseen.shape:
            fov = cv2.resize(fov, (k.width, k.height), interpolation=cv2.INTER_NEAREST)
        unseen |= fov <= 127
    return unseen


def write_depth_pngs(folder: Path, depths: dict[int, np.ndarray]) -> float:
    """16-bit PNGs with one scale for the sequence (world units per count), in the manifest."""
    top = max(float(d.max()) for d in depths.values()) if depths else 1.0
    scale = max(top, 1e-6) / PNG_MAX
    for i, d in depths.items():
        png = np.clip(np.round(d / scale), 0, PNG_MAX).astype(np.uint16)
        cv2.imwrite(str(folder / frame_file(i, ".png")), png)
    return scale


@contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """torch on `n` threads inside (None: as it is). A baked map is ray casts (Embree's own
    threads) and a few hundred volume-rendered rays: two OpenMP threads spinning beside
    Embree's made a C3VD map 50 ms instead of 23."""
    import torch

    before = torch.get_num_threads()
    if n is not None:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)
