"""How a depth map is rendered from a case's trained field: the baked surface (the default) or
the field itself, at the poses the field was fitted to (a dynamic field: always the field, each
frame at its own time). The depth stage renders the keyframes
with it; a recording renders the frames between them with the same, one window at a time."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from endopipe.stages.camera import Camera
from endopipe.stages.centerline.view import CenterlineView
from endopipe.stages.depth.config import DepthConfig
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import PosesView

#: depth.field_depth -> the volume renderer's map that gives it (`render_image`)
DEPTH_OF = {"median": "median", "expected": "depth"}
#: ... and the log's words for it
READ_OUT_WHY = {
    "median": "the median of its weights (depth.field_depth; no measured depth trained the "
    "field, so haze in front of the wall would pull its mean off it)",
    "expected": "the mean of its weights (depth.field_depth), which measured depth trained",
}


def field_depth(cfg: DepthConfig, nerf: NerfView) -> str:
    """depth.field_depth resolved: auto is the expected depth where measured depth trained
    the field (it fits that), the median where nothing did (or a field that did not say)."""
    if cfg.field_depth != "auto":
        return cfg.field_depth
    return "median" if nerf.summary.depth_supervised is False else "expected"


#: (intrinsics, c2w, frame index, colour) -> {depth, opacity, hazy[, rgb]}
Render = Callable[[Camera, np.ndarray, int, bool], dict[str, Any]]


@dataclass
class FieldSight:
    """A case's field made ready to render depth: the renderer, the working camera, the poses
    the field was fitted to (refined, when it refined) and the bake's time."""

    render: Render
    camera: Camera
    c2w: dict[int, np.ndarray]
    model: Any
    bake_s: float

    @classmethod
    def open(
        cls,
        cfg: DepthConfig,
        ingest: IngestView,
        poses: PosesView,
        centerline: CenterlineView,
        nerf: NerfView,
    ) -> FieldSight:
        from endopipe.stages.nerf.render import pick_device

        model = nerf.model(pick_device(cfg.device))
        k = poses.intrinsics
        if (k.width, k.height) != (ingest.width, ingest.height):
            k = k.scaled(ingest.width, ingest.height)
        c2w = nerf.c2w(poses)
        prior = centerline.prior()
        t0 = time.perf_counter()
        render = make_renderer(cfg, model, prior, [c2w[i] for i in poses.registered], k, nerf)
        return cls(render, k, c2w, model, time.perf_counter() - t0)


def stereo_sight(ingest: IngestView, poses: PosesView) -> FieldSight:
    """A stereo pair alone (no field): each frame's depth is the rig's, measured in ingest, and
    unknown where the matcher could not vouch for it; nothing is rendered."""
    k = poses.intrinsics
    if (k.width, k.height) != (ingest.width, ingest.height):
        k = k.scaled(ingest.width, ingest.height)

    def render(k: Camera, c2w: np.ndarray, i: int, colour: bool) -> dict[str, Any]:
        depth = ingest.stereo_depth(i)
        if depth is None:
            depth = np.zeros((k.height, k.width), np.float32)
        measured = (depth > 0).astype(np.float32)
        return {"depth": depth.copy(), "opacity": measured, "hazy": np.zeros(depth.shape, bool)}

    return FieldSight(render, k, dict(poses.c2w), None, 0.0)


def spread_limit(cfg: DepthConfig, prior) -> float | None:
    """The baked read-out's spread limit: depth.max_spread, or depth.free_max_spread in a free
    scene (its far bake's ramps are as wide as its grid's cells; a volume-rendered ray keeps
    depth.max_spread)."""
    return cfg.free_max_spread if prior.kind == "none" else cfg.max_spread


def bakes_near(cfg: DepthConfig, prior) -> bool:
    """depth.bake_near resolved: auto is on with a lumen prior, off in a free scene."""
    return cfg.bake_near == "on" or (cfg.bake_near == "auto" and prior.kind != "none")


def make_renderer(cfg: DepthConfig, model, prior, c2ws: list[np.ndarray], k, nerf: NerfView):
    """A function (intrinsics, c2w, frame, colour) -> {depth, opacity[, rgb]}; depth is 0
    where the ray found no surface (unless `fill`). Colour is the nerf stage's own rendering
    of the held-out frame when it kept one (the field is the same: no second render)."""
    from endopipe.stages.nerf.render import render_image, surface_found

    read_out = field_depth(cfg, nerf)

    def colour_of(k, c2w, i) -> np.ndarray:
        kept = nerf.heldout_rgb(i)
        if kept is not None and kept.shape[:2] == (k.height, k.width):
            return kept
        return render_image(model, prior, k, c2w, colour=True)["rgb"]

    if cfg.renderer == "field" or model.field.dynamic:
        # A dynamic field has no one surface to bake: each frame renders at its own time.
        position = {f: p for p, f in enumerate(getattr(model, "meta", {}).get("frame_ids", []))}
        if model.field.dynamic:
            coarse, fine = cfg.dynamic_samples
            sampling = model.cfg.sampling.model_copy(
                update={"render_coarse": coarse, "render_fine": fine}
            )
            model.cfg = model.cfg.model_copy(update={"sampling": sampling})

        def render_field(k, c2w, i, colour):
            with model.at_frame(position.get(i)):
                # a dynamic field's colour: the nerf stage's render (with its full samples)
                own = colour and model.field.dynamic
                out = render_image(model, prior, k, c2w, colour=colour and not own)
                if own:
                    out["rgb"] = colour_of(k, c2w, i)
            found, out["hazy"] = surface_found(
                out["opacity"], out["spread"], cfg.min_opacity, cfg.max_spread
            )
            out["depth"] = np.where(found, out[DEPTH_OF[read_out]], 0.0)
            return out

        return render_field
    from endopipe.stages.nerf.baked import NEAR_REACH_RADII, BakedSurface, FarSettings

    far = None
    if cfg.far == "baked":
        far = FarSettings(
            max_nodes=cfg.far_max_nodes,
            levels=tuple(cfg.far_levels),
            faint=cfg.far_faint,
        )
    baked = BakedSurface.bake(
        model,
        prior,
        c2ws,
        k,
        cfg.bake_voxels_per_radius,
        cfg.bake_density_level,
        reach_radii=NEAR_REACH_RADII if bakes_near(cfg, prior) else 0.0,
        min_component_radii=cfg.bake_min_component,
        far=far,
    )

    max_spread = spread_limit(cfg, prior)

    def render(k, c2w, i, colour):
        out = baked.render_depth(
            k, c2w, cfg.min_opacity, cfg.fill, max_spread, read_out == "median"
        )
        if colour:  # colour needs the albedo field: only for held-out frames
            out["rgb"] = colour_of(k, c2w, i)
        return out

    return render
