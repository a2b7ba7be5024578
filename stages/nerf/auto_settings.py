"""The NeRF settings left `auto` (and those a scene's kind decides), resolved before training
from what the earlier stages found: the prior and how well it fits, a still camera, a scene no
prior bounds, a scene that moves, an unwarped grid. The stage's recorded config is unchanged;
the saved model carries the resolved one (docs/method.md says why each)."""

from __future__ import annotations

import numpy as np

from endopipe.stages.nerf.config import NerfConfig
from endopipe.stages.nerf.scene import SceneBox


def regularise_far_view(cfg: NerfConfig, box: SceneBox, log) -> NerfConfig:
    """The `far_view` regularisers when `field.warp: auto` left the grid unwarped: far surface
    then lies in cells as fine as the near ones, each seen by few pixels (C3VD's far lumen came
    out blocky and speckled without them). The stage's recorded config is unchanged."""
    if cfg.field.warp != "auto" or box.warped:
        return cfg
    fv = cfg.far_view
    tv = max(cfg.field.tensorf.tv_weight, fv.tv_weight)
    distortion = max(cfg.loss.distortion_weight, fv.distortion_weight)
    res = cfg.field.tensorf.res_final
    if fv.res_final is not None:
        res = max(min(res, fv.res_final), cfg.field.tensorf.res_init)
    tensorf = cfg.field.tensorf.model_copy(update={"tv_weight": tv, "res_final": res})
    field = cfg.field.model_copy(update={"tensorf": tensorf})
    loss = cfg.loss.model_copy(update={"distortion_weight": distortion})
    log(
        f"unwarped grid: density TV {tv:g}, distortion loss {distortion:g}, {res} nodes along "
        "the longest side (nerf.far_view)"
    )
    return cfg.model_copy(update={"field": field, "loss": loss})


def weigh_prior(cfg: NerfConfig, prior, log) -> NerfConfig:
    """L_prior's weight scaled by how well the prior fits the SfM points (its `weight`, from
    the centerline stage); off without a prior. The stage's recorded config is unchanged: the
    scaling is a function of it and of the centerline stage's output."""
    weight = float(getattr(prior, "weight", 1.0))
    if not cfg.loss.prior or weight >= 1.0:
        return cfg
    loss = cfg.loss.model_copy(
        update={"lambda_prior": cfg.loss.lambda_prior * weight, "prior": weight > 0}
    )
    log(
        f"lumen prior {prior.kind}: L_prior weight x {weight:.2f}"
        + (" (off)" if weight <= 0 else "")
    )
    return cfg.model_copy(update={"loss": loss})


def choose_geometry(cfg: NerfConfig, prior, log) -> NerfConfig:
    """geometry auto: a signed distance over the cavity prior's wall, a density otherwise (see
    `FieldConfig.geometry` for what was measured). Resolved before training, so the saved
    model says which it is."""
    if cfg.field.geometry != "auto":
        return cfg
    geometry = "sdf" if prior.kind == "cavity" else "density"
    if geometry == "sdf":
        log("geometry auto: a signed distance over the cavity prior's wall")
    field = cfg.field.model_copy(update={"geometry": geometry})
    return cfg.model_copy(update={"field": field})


def still_camera_settings(cfg: NerfConfig, poses, log) -> NerfConfig:
    """A still camera's field: its grid over its view's frustum over tissue that moves, else
    unwarped (when `field.warp` is auto), its shading without n.l, more steps
    (`train.still_steps`) and its stereo rays' density held at their depth (why: below and in
    `LossConfig.stereo_spread`, whose auto is resolved here for any camera)."""
    spread = cfg.loss.spread_weight(poses.still)
    cfg = cfg.model_copy(update={"loss": cfg.loss.model_copy(update={"stereo_spread": spread})})
    if poses.still and cfg.field.warp == "auto":
        # The warp keeps fine cells around the camera path; a still camera's path is a point
        # and its scene lies a typical distance away, in the coarse cells (held-out 15.9 dB
        # warped on a still da Vinci clip at 600 steps). An axis-aligned box around its view
        # wastes the cells beside the view near the camera: over tissue that moves, the grid
        # is the view's frustum (the cutting clip 32.92 dB against 32.20, the pulled wall
        # 40.24 against 37.99). A still rig over a still scene kept the box: its mesh came
        # out 7.05% of the radius off against 6.08 over the frustum (docs/results.md).
        frustum = field_is_dynamic(cfg, poses)
        field = cfg.field.model_copy(update={"warp": "frustum" if frustum else False})
        cfg = cfg.model_copy(update={"field": field})
        if frustum:
            log("grid over the view's frustum: a still camera over tissue that moves")
        else:
            log("grid warp off: the camera stands still, its scene lies away from it")
    if poses.still and cfg.shading.normal_term:
        # Seen from one place, a surface's tilt is not measured: n.l lit the field's noisy
        # normals into black speckles (held-out 17.1 dB against 26.6 without, a still da Vinci
        # clip at 600 steps). The light still falls off with distance.
        shading = cfg.shading.model_copy(update={"normal_term": False})
        cfg = cfg.model_copy(update={"shading": shading})
        log("shading without n.l: a still camera does not see a surface's tilt")
    if poses.still and cfg.train.still_steps > 1.0:
        # The time budget guards the planned steps against a slow machine: it grows with them,
        # or it would cut a still camera's training short on a machine of the reference speed
        # (the pulled wall with its stereo rays stopped at step 4669 of 6000 at 600 s).
        factor = cfg.train.still_steps
        steps = round(cfg.train.steps * factor)
        budget = cfg.train.time_budget_s
        budget = None if budget is None else budget * factor
        train = cfg.train.model_copy(update={"steps": steps, "time_budget_s": budget})
        cfg = cfg.model_copy(update={"train": train})
        within = "" if budget is None else f", within {budget:g} s"
        log(
            f"{steps} steps ({factor:g} x nerf.train.steps{within}): a still camera's "
            "field is starved of rays, and its held-out frames are new times, not new views"
        )
    return cfg


def free_scene_settings(cfg: NerfConfig, prior, poses, log) -> NerfConfig:
    """A moving camera with no lumen prior (a free scene: the sinus): the grid warped, the
    shading without n.l, an exposure a frame and an albedo over time, where each setting is
    `auto` (the n.l term: always). Measured on the real sinus recording's first window, 1500
    steps (docs/results.md): held-out 23.5 dB against 17.2, training fit 27.0 against 18.3,
    the field's depth at the authors' points 0.086 against 0.092. Why each: the points'
    reach (past every point seen) sizes an unwarped grid to ten times their median depth, in
    cells 10-20 px wide at the surface; without a wall the density's normals are its own
    noise, which n.l lit into dark speckles (a sinus stretch: held-out 18.8 dB with it, 24.2
    without); the scope's exposure follows what it looks at. Other scenes: exposure off."""
    free = prior.kind == "none" and not poses.still and not poses.one_pair
    shading = cfg.shading.model_copy(
        update={"exposure": free if cfg.shading.exposure == "auto" else cfg.shading.exposure}
    )
    if not free:
        return cfg.model_copy(update={"shading": shading})
    field = cfg.field
    update: dict = {}
    if field.warp == "auto":
        update["warp"] = True
    if field.appearance_time == "auto":
        update["appearance_time"] = field.encoding == "tensorf"
    shading = shading.model_copy(update={"normal_term": False})
    log(
        "no lumen prior, a moving camera: grid warped about the camera path, shading without "
        f"n.l, exposure a frame {'on' if shading.exposure is True else 'off'}"
    )
    return cfg.model_copy(update={"shading": shading, "field": field.model_copy(update=update)})


#: Frames a dynamic field's training step draws its rays from (`train.frames_per_step` auto).
STILL_FRAMES_PER_STEP = 8


def field_is_dynamic(cfg: NerfConfig, poses) -> bool:
    """`field.dynamic` as resolved: as given, or (auto) where the poses stage found the scene
    moving (tissue under a still camera)."""
    if cfg.field.dynamic == "auto":
        return poses.motion is not None and poses.motion.scene == "moving"
    return cfg.field.dynamic is True


def choose_dynamic(cfg: NerfConfig, poses, n_frames: int, log) -> NerfConfig:
    """field.dynamic auto: a field that changes with time where the poses stage found the scene
    moving under a still camera, the static field otherwise; the log says which and why.
    A dynamic field's frames are not one scene at different places, so the multi-frame depth
    consistency (which warps one frame's depth into another's) is off."""
    motion = poses.motion
    dynamic = field_is_dynamic(cfg, poses)
    if cfg.field.dynamic == "auto":
        why = (
            f"the footage is {motion.label}"
            if motion is not None
            else "the footage's motion was not judged (poses.motion.check off)"
        )
        log(f"field auto: {'dynamic (space-time planes)' if dynamic else 'static'}: {why}")
    nodes = cfg.field.time_nodes or int(np.clip(round(n_frames / 2), 4, 64))
    if cfg.train.frames_per_step == "auto":
        per_step = STILL_FRAMES_PER_STEP if dynamic else 0
        cfg = cfg.model_copy(
            update={"train": cfg.train.model_copy(update={"frames_per_step": per_step})}
        )
    if not dynamic:
        update: dict = {"dynamic": False}
        timed = cfg.field.appearance_time
        if timed == "auto":
            timed = cfg.field.encoding == "tensorf" and cfg.loss.prior
            if not cfg.loss.prior:
                log(
                    "albedo over time off: no lumen prior shapes the geometry (without one an "
                    "albedo over time takes what the shape should explain)"
                )
        update["appearance_time"] = timed
        if timed:
            update["time_nodes"] = nodes
            log(f"albedo over time: {nodes} time nodes over {n_frames} frames, a rigid geometry")
        return cfg.model_copy(update={"field": cfg.field.model_copy(update=update)})
    field = cfg.field.model_copy(
        update={
            "dynamic": True,
            "time_nodes": nodes,
            "geometry": "density",
            "appearance_time": False,  # the whole field changes with time already
        }
    )
    loss = cfg.loss.model_copy(update={"geo": False})
    per = cfg.train.frames_per_step
    batch = f"; each step's rays from {per} frames" if per else ""
    log(f"dynamic field: {nodes} time nodes over {n_frames} frames; multi-frame depth off{batch}")
    return cfg.model_copy(update={"field": field, "loss": loss})


def choose_proposal(cfg: NerfConfig, log) -> NerfConfig:
    """sampling.proposal auto: the coarse density copy proposes the first pass's samples where
    a lumen prior shapes the density (weigh_prior left it on); without one the density is
    diffuse and its coarse copy misplaces them."""
    if cfg.sampling.proposal != "auto":
        return cfg
    on = bool(cfg.loss.prior)
    if not on:
        log("proposal grid off: no lumen prior shapes the density; every pass reads the field")
    return cfg.model_copy(update={"sampling": cfg.sampling.model_copy(update={"proposal": on})})
