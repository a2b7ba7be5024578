"""nerf: a NeRF of the lumen regularised by the anatomical prior (seed §3), fast on a CPU.

Trains on the registered frames except every 8th (index % 8 == 0, held out and evaluated), with
ray bounds and L_prior from the centerline stage's tube prior. Writes model.pt (see render.py to
use it), train_log.csv, loss.png, heldout.png and metrics.json; resumes from checkpoint.pt
after a kill (the stage is resumable, its temporary folder survives).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from endopipe.pipeline.errors import EndopipeError
from endopipe.pipeline.executors.threads import auto_threads
from endopipe.pipeline.stage import Stage, StageContext
from endopipe.stages.camera import Camera, image_directions, lens_valid_mask, pixel_rays
from endopipe.stages.centerline.view import CenterlineView
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.nerf.auto_settings import (
    choose_dynamic,
    choose_geometry,
    choose_proposal,
    free_scene_settings,
    regularise_far_view,
    still_camera_settings,
    weigh_prior,
)
from endopipe.stages.nerf.bounds import PriorBounds
from endopipe.stages.nerf.colour_phase import refit_if_pinned
from endopipe.stages.nerf.config import NerfConfig
from endopipe.stages.nerf.data import FrameSet, holdout_split
from endopipe.stages.nerf.evaluate import evaluate, plot_log
from endopipe.stages.nerf.files import MODEL_FILE
from endopipe.stages.nerf.point_refine import refine_points
from endopipe.stages.nerf.pose_refine import record, refinement_wanted
from endopipe.stages.nerf.prior_depth import PriorRays, prior_depth_targets
from endopipe.stages.nerf.render import pick_device, save_model
from endopipe.stages.nerf.scene import FRUSTUM_NEAREST, Frustum, SceneBox
from endopipe.stages.nerf.shading_depth import only_shading_places_depth, shading_depth
from endopipe.stages.nerf.sparse_depth import SparseDepth, sparse_depth_targets
from endopipe.stages.nerf.stereo_depth import stereo_depth_targets
from endopipe.stages.nerf.summary import NerfSummary
from endopipe.stages.nerf.train import CHECKPOINT, Trainer
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import PosesView


def load_prior(centerline) -> object:
    """The LumenPrior of the centerline stage (its folder, or a view with a folder)."""
    from endopipe.stages.centerline.prior import load_prior as read_prior

    if hasattr(centerline, "prior") and not callable(centerline.prior):
        return centerline.prior
    folder = Path(getattr(centerline, "folder", centerline))
    path = folder / "prior.npz" if folder.is_dir() else folder
    if not path.is_file():
        raise EndopipeError(f"no lumen prior at {path}; re-run the centerline stage")
    return read_prior(path)


def fit_box(
    c2w: list[np.ndarray],
    camera: Camera,
    hw: tuple[int, int],
    prior,
    cfg,
    points: np.ndarray | None = None,
    log=None,
) -> SceneBox:
    """Scene box around what the cameras can see inside the prior's (inflated) lumen, and as
    far as the samples go past the wall of a prior the SfM points contradict (the cavity
    preset's ellipsoid around a colon ended the box 6.5 radii down the lumen, the tube's at
    14.5: the far lumen had no field). With `field.warp: auto` the grid is warped only when
    the SfM `points` lie mostly near the camera path, where the warp keeps its fine cells
    (C3VD: 14% of them do, the bench colon 91%)."""
    centres = np.array([c[:3, 3] for c in c2w])
    box0 = SceneBox.fit(centres, float(prior.typical_radius), centres)
    box0.lo, box0.hi = np.full(3, -1.0), np.full(3, 1.0)
    pb = PriorBounds(prior, box0, cfg)
    h, w = hw
    vv, uu = np.meshgrid(np.linspace(0, h - 1, 12), np.linspace(0, w - 1, 16), indexing="ij")
    u = torch.tensor(uu.ravel(), dtype=torch.float32)
    v = torch.tensor(vv.ravel(), dtype=torch.float32)
    pts = []
    for c in c2w:
        cs = torch.tensor(box0.c2w_to_scene(c), dtype=torch.float32)
        o, d = pixel_rays(camera, cs, u, v)
        _, far, _ = pb.bounds(o, d, pb.margin, wall=True, past_points=True)
        pts.append(box0.scene_to_world_np((o + far[:, None] * d).numpy()))
    f = cfg.field

    def fit(warp: bool) -> SceneBox:
        return SceneBox.fit(
            centres,
            float(prior.typical_radius),
            np.concatenate(pts),
            core_pad=f.warp_core_pad if warp else None,
            soft=f.warp_soft,
        )

    if f.warp == "frustum":
        return frustum_box(fit(False), c2w[0], camera, hw, prior, cfg, log)
    box = fit(f.warp is not False)
    share = box.core_share(points)
    if f.warp == "auto" and share is not None and share < f.warp_min_inside:
        box = fit(False)
    if log is not None and share is not None and f.warp == "auto":
        log(
            f"grid warp {'on' if box.warped else 'off'}: {share:.0%} of the SfM points lie "
            f"within {f.warp_core_pad:g} radii of the camera path's box"
        )
    return box


def frustum_box(box: SceneBox, c2w: np.ndarray, camera: Camera, hw, prior, cfg, log=None):
    """`box` with its grid over the view of the camera at `c2w` (scene.Frustum): the image's
    span of ray directions (a 5% margin a side, a stereo rig's other eye near it) and the
    depths its rays are sampled over."""
    h, w = hw
    vv, uu = np.meshgrid(np.linspace(0, h - 1, 24), np.linspace(0, w - 1, 32), indexing="ij")
    c2w_s = box.c2w_to_scene(c2w)
    u, v = (torch.tensor(a.ravel(), dtype=torch.float32) for a in (uu, vv))
    o, d = pixel_rays(camera, torch.tensor(c2w_s, dtype=torch.float32), u, v)
    pb = PriorBounds(prior, box, cfg)
    near, far, _ = pb.bounds(o, d, pb.margin, wall=True, past_points=True)
    rot = c2w_s[:3, :3].T  # scene -> camera
    dc = d.numpy().astype(np.float64) @ rot.T
    uv = dc[:, :2] / dc[:, 2:3]
    span = uv.max(0) - uv.min(0)
    z_hi = float(far.max())
    z_lo = max(float(near.min()), FRUSTUM_NEAREST * z_hi)
    lo = np.array([*(uv.min(0) - 0.05 * span), np.log(z_lo) - 0.02])
    hi = np.array([*(uv.max(0) + 0.05 * span), np.log(z_hi) + 0.02])
    box.frustum = Frustum(rot, c2w_s[:3, 3], lo, hi, cfg.field.frustum_depth_nodes)
    if log is not None:
        depths = f"{z_lo * box.scale:.3g}-{z_hi * box.scale:.3g}"
        log(f"the grid over the view's frustum: depth {depths} (world units)")
    return box


def load_sparse_depth(
    ingest,
    poses,
    positions: dict[int, int],
    box,
    cfg: NerfConfig,
    device: torch.device,
    grey: dict[int, np.ndarray] | None = None,
    log: Callable[[str], None] = print,
):
    """SfM-point depth targets of the training frames (None when the poses have no tracks).
    Pixels are rescaled when the poses' camera has another resolution than the frames. With
    `grey`, the training frames (given when `nerf.loss.sparse_refine`), the points are refined."""
    obs = poses.observations(ingest.index_by_name())
    k = poses.intrinsics
    if obs is not None:
        obs.resize((k.width, k.height), (ingest.width, ingest.height))
    lc = cfg.loss
    if obs is not None and grey:
        train = {f: poses.c2w[f] for f in grey if f in poses.c2w}
        camera = k.scaled(ingest.width, ingest.height)
        t = time.perf_counter()
        obs, moved = refine_points(obs, camera, train, grey)
        log(
            f"SfM points refined by patch correlation: {moved.mean():.0%} of their pixels "
            f"moved ({time.perf_counter() - t:.1f} s)"
        )
    return sparse_depth_targets(
        obs,
        positions,
        poses.c2w,
        box.scale,
        (ingest.height, ingest.width),
        lc.sparse_min_track,
        lc.sparse_max_error,
        lc.sparse_min_angle,
        device,
        usable=sparse_usable(poses, k.scaled(ingest.width, ingest.height), lc.sparse_lens_share),
    )


def load_stereo_depth(
    ingest: IngestView,
    poses: PosesView,
    positions: dict[int, int],
    box: SceneBox,
    cfg: NerfConfig,
    device: torch.device,
    log: Callable[[str], None],
) -> SparseDepth | None:
    """The stereo rig's depth of the training frames as targets, in millimetres: only with
    metric poses (the poses stage scaled them by the same depth)."""
    if cfg.loss.stereo_weight <= 0 or not ingest.has_stereo:
        return None
    if not poses.metric:
        log("stereo depth unused: the poses are not metric (too few SfM points had stereo depth)")
        return None
    lc = cfg.loss
    stereo = stereo_depth_targets(
        ingest, positions, 1.0, box.scale, lc.stereo_per_frame, device, cfg.train.seed
    )
    rays, frames = (len(stereo), len(torch.unique(stereo.frame))) if stereo else (0, 0)
    line = f"stereo depth: {rays} matched-pixel rays from {frames} frames"
    spread = lc.spread_weight(poses.still)
    if rays and spread > 0:
        line += f"; each ray's density held at its depth (nerf.loss.stereo_spread {spread:g})"
    log(line)
    return stereo


def load_prior_depth(
    ingest: IngestView,
    poses: PosesView,
    camera: Camera,
    positions: dict[int, int],
    cfg: NerfConfig,
    device: torch.device,
    log: Callable[[str], None],
) -> PriorRays | None:
    """Relative depth of the training frames as per-frame targets, on the pixels their masks
    keep: the user's `--depth-prior`, or, for a still camera with nothing else to place depth
    (no stereo, no depth given), its depth from the light's fall-off (nerf.shading_depth)."""
    lc = cfg.loss
    shading = only_shading_places_depth(ingest, poses)
    weight = lc.shading_prior_weight if shading else lc.depth_prior_weight
    if weight <= 0 or not (shading or ingest.has_depth_prior):
        return None
    usable = {i: ingest.mask(i) > 127 for i in positions}
    prior_of, what = ingest.depth_prior, "depth prior"
    if shading:
        directions = image_directions(camera)  # build_frames' camera: the working size

        def prior_of(i: int) -> np.ndarray:
            return shading_depth(ingest.image(i), usable[i], directions, cfg.shading.gamma)

        what = "depth from shading (the light's fall-off)"
    rays = prior_depth_targets(
        prior_of,
        positions,
        usable,
        lc.depth_prior_per_frame,
        lc.depth_prior_rays,
        device,
        cfg.train.seed,
        weight,
    )
    frames = len(rays.frame) if rays else 0
    log(
        f"{what}: {len(rays) if rays else 0} rays from {frames} of {len(positions)} "
        "training frames (relative: a scale and shift fitted per frame)"
    )
    return rays


def sparse_usable(poses: PosesView, camera: Camera, share: float) -> np.ndarray:
    """The pixels whose SfM points' depth the field may follow: those the lens model reaches,
    within `share` of the radius an estimated lens was fitted within."""
    usable = lens_valid_mask(camera)
    past = poses.past_fitted_radius(camera, share)
    return usable if past is None else usable & ~past


def sparse_depth_line(sparse: SparseDepth | None, min_angle: float) -> str:
    """The log line of the SfM-point depth: how many rays, and from which viewing angle."""
    if not sparse:
        return "sparse depth: no SfM-point rays (the poses have no usable tracks)"
    line = f"sparse depth: {len(sparse)} SfM-point rays"
    if sparse.min_angle < min_angle:
        return (
            f"{line}, the wider half of the points (seen under >= {sparse.min_angle:.1f} deg: "
            f"the camera moved too little for {min_angle:g} deg, nerf.loss.sparse_min_angle)"
        )
    return f"{line} (seen under >= {sparse.min_angle:g} deg)" if min_angle > 0 else line


def frame_times(ingest, ids: list[int]) -> list[float]:
    """Each frame's time: its time in the video, else its position in the input."""
    frames = [ingest.frame(i) for i in ids]
    if all(f.time_s is not None for f in frames):
        return [float(f.time_s) for f in frames]
    return [float(f.source_index) for f in frames]


def build_frames(ingest, poses, device: torch.device):
    """Registered frames (endopipe order): images in [0, 1], usable masks, world c2w."""
    ids = [i for i in poses.registered if i < len(ingest.frames)]
    if len(ids) < 2:
        raise EndopipeError(f"nerf needs at least 2 registered frames, got {len(ids)}")
    k = poses.intrinsics
    if (k.width, k.height) != (ingest.width, ingest.height):
        k = k.scaled(ingest.width, ingest.height)
    images = np.stack([ingest.image(i) for i in ids]).astype(np.float32) / 255.0
    masks = np.stack([ingest.mask(i) > 127 for i in ids]) & lens_valid_mask(k)[None]
    c2w = [poses.c2w[i] for i in ids]
    return ids, k, images, masks, c2w


@dataclass
class TrainingSetUp:
    """What training starts from: the settings as fitted to the case, the trainer, the frames."""

    cfg: NerfConfig
    trainer: Trainer
    prior: object
    ids: list[int]  # registered frames, endopipe order
    camera: Camera
    c2w: list[np.ndarray]  # world, by position in ids
    train_ids: list[int]
    held_ids: list[int]
    pos: dict[int, int]  # frame -> position in ids
    refine: bool


def set_up_training(
    cfg: NerfConfig, ingest, poses, centerline, out: Path, log: Callable[[str], None]
) -> TrainingSetUp:
    """The prior, the scene box, the frames, the SfM-point depth and the trainer, as the stage
    trains them (scripts/bench_nerf_step.py times steps of the same trainer)."""
    device = pick_device(cfg.train.device)
    prior = load_prior(centerline)
    cfg = weigh_prior(cfg, prior, log)
    ids, k, images, masks, c2w = build_frames(ingest, poses, device)
    cfg = still_camera_settings(cfg, poses, log)
    cfg = free_scene_settings(cfg, prior, poses, log)
    cfg = choose_dynamic(cfg, poses, len(ids), log)
    cfg = choose_proposal(cfg, log)
    cfg = choose_geometry(cfg, prior, log)
    box = fit_box(c2w, k, images.shape[1:3], prior, cfg, poses.points(), log)
    cfg = regularise_far_view(cfg, box, log)
    frames = FrameSet(images, masks, np.stack([box.c2w_to_scene(c) for c in c2w]), k, ids, device)
    train_ids, held_ids = holdout_split(ids, cfg.train.holdout_every)
    pos = {i: p for p, i in enumerate(ids)}
    sparse = None
    if cfg.loss.sparse_weight > 0:
        train_pos = {i: pos[i] for i in train_ids}
        grey = {i: images[pos[i]].mean(-1) for i in train_ids} if cfg.loss.sparse_refine else None
        sparse = load_sparse_depth(ingest, poses, train_pos, box, cfg, device, grey, log)
        log(sparse_depth_line(sparse, cfg.loss.sparse_min_angle))
    stereo = load_stereo_depth(ingest, poses, {i: pos[i] for i in train_ids}, box, cfg, device, log)
    relative = load_prior_depth(ingest, poses, k, {i: pos[i] for i in train_ids}, cfg, device, log)
    refine = refinement_wanted(cfg.pose_refine.mode, poses.file.source)
    trainer = Trainer(
        cfg,
        frames,
        [pos[i] for i in train_ids],
        prior,
        box,
        out,
        log,
        sparse,
        refine,
        stereo,
        relative,
    )
    trainer.model.set_frame_times(frame_times(ingest, ids))
    return TrainingSetUp(cfg, trainer, prior, ids, k, c2w, train_ids, held_ids, pos, refine)


#: Why a stereo pair alone trains no field (NerfSummary.skipped).
NO_FIELD_ONE_PAIR = "a stereo pair alone: one view, its depth the rig's"


class Nerf(Stage):
    """NeRF with near-light shading and the lumen prior (TensoRF VM grid by default)."""

    name = "nerf"
    needs = ("ingest", "poses", "centerline")
    # 14: the held-out depth scored by the truth's own protocols (an affine proxy only up to
    # scale and shift, the depth as it is only with metric poses); 13: that refit on a pool of
    # rays rendered once, as frames are rendered; 12: the albedo fitted again when a channel sat
    # at its ceiling; 11: a moving camera with no lumen prior: warped grid, no n.l, exposure,
    # albedo over time; 10: no field for a stereo pair alone; 9: the proposal grid, the depth
    # rays rendered with the batch, exposures a channel, the fit measured; 8: the user's depth
    # prior (relative) shapes the field; 7: stereo depth
    version = 14
    Config = NerfConfig
    Summary = NerfSummary
    View = NerfView
    resumable = True

    def run(self, ctx: StageContext[NerfConfig]) -> NerfSummary:
        cfg = ctx.config
        threads = torch.get_num_threads()
        torch.set_num_threads(cfg.train.threads or auto_threads())
        try:
            return self._run(ctx, cfg)
        finally:
            torch.set_num_threads(threads)

    def _run(self, ctx: StageContext[NerfConfig], cfg: NerfConfig) -> NerfSummary:
        ingest, poses = ctx.input(IngestView), ctx.input(PosesView)
        if ingest.one_pair:
            ctx.log(f"no field: {NO_FIELD_ONE_PAIR}")
            return NerfSummary(
                steps=0, train_frames=0, heldout_frames=0, train_s=0.0, rays_per_s=0.0,
                skipped=NO_FIELD_ONE_PAIR,
            )  # fmt: skip
        run = set_up_training(cfg, ingest, poses, ctx.input(CenterlineView), ctx.out, ctx.log)
        cfg, trainer = run.cfg, run.trainer
        if trainer.core_fraction < cfg.loss.core_fraction:
            ctx.log(
                f"L_prior's empty core: {trainer.core_fraction:.2f} of the wall (loss."
                f"core_fraction {cfg.loss.core_fraction:g}; the SfM points lie inside a wider one)"
            )
        resumed = trainer.try_resume()
        start = trainer.step_i
        if resumed:
            ctx.log(f"resuming from checkpoint at step {start}")
        with ctx.progress("nerf", total=cfg.train.steps) as advance:
            trainer.fit(advance)
        budget_stopped = trainer.step_i < cfg.train.steps
        if budget_stopped:
            ctx.log(
                f"stopped by nerf.train.time_budget_s ({cfg.train.time_budget_s:g} s) at step "
                f"{trainer.step_i} of {cfg.train.steps}: the schedule ran on time, so this "
                "result depends on the machine's speed and load"
            )
        trainer.save_checkpoint()  # a crash while evaluating resumes here, not steps back
        colour = refit_if_pinned(trainer, ctx.log, ctx.progress)
        held_refined = trainer.refine_heldout([run.pos[i] for i in run.held_ids])
        c2w_used = trainer.world_poses(run.c2w)  # refined (world frame) when refinement ran
        pose_summary = record(
            ctx.out, run.ids, run.held_ids, run.c2w, c2w_used, run.refine, held_refined
        )
        trainer.write_log(ctx.out / "train_log.csv")
        plot_log(trainer.rows, ctx.out / "loss.png")
        save_model(
            ctx.out / MODEL_FILE,
            trainer.model,
            {
                "frame_ids": run.ids,
                "train": run.train_ids,
                "heldout": run.held_ids,
                "units": poses.file.units,
                "pose_refine": run.refine,
            },
        )
        model = trainer.model.eval()
        rays_per_s = cfg.train.batch_rays * trainer.step_i / max(trainer.elapsed, 1e-9)
        evaluation = evaluate(
            model,
            run.prior,
            ingest,
            run.camera,
            c2w_used,
            run.ids,
            run.held_ids,
            run.train_ids,
            cfg,
            ctx,
            trainer.depth_sources(),
        )
        ctx.log(evaluation.fit_said)
        if evaluation.psnr_exposure_interpolated is not None:
            ctx.log(
                "held-out frames scored with their exposure fitted to the frame's left half "
                f"(a gain a channel; the neighbour average too): with the exposure their "
                f"trained neighbours interpolate, {evaluation.psnr_exposure_interpolated:.2f} dB"
            )
        (ctx.out / CHECKPOINT).unlink(missing_ok=True)
        evaluation.write(ctx.out)
        return NerfSummary(
            steps=trainer.step_i,
            planned_steps=cfg.train.steps,
            budget_stopped=budget_stopped,
            train_frames=len(run.train_ids),
            heldout_frames=len(run.held_ids),
            train_s=round(trainer.elapsed, 2),
            rays_per_s=round(rays_per_s, 1),
            render_ms=evaluation.render_rgb_ms,
            heldout_psnr=evaluation.psnr,
            train_psnr=evaluation.train_psnr,
            neighbour_psnr=evaluation.neighbour_psnr,
            fit=evaluation.fit,
            depth=evaluation.depth,
            resumed_from=start,
            device=str(trainer.device),
            threads=torch.get_num_threads(),
            pose_refine=pose_summary,
            grid_warp=trainer.box.warped,
            core_fraction=trainer.core_fraction,
            geometry=run.cfg.field.geometry,
            time_nodes=run.cfg.field.time_nodes if run.cfg.field.dynamic is True else None,
            depth_supervised=trainer.depth_supervised,
            colour_refit=colour,
        )


def describe_config() -> str:
    return json.dumps(NerfConfig().model_dump(mode="json"), indent=1)
