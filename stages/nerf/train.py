"""The training loop: Adam with per-group learning rates and exponential decay, the loss terms,
atomic checkpoints every N steps and resumption from them (the step count goes on), and the
joint pose refinement (pose_refine.py) of the training frames, then of the held-out ones."""

from __future__ import annotations

import csv
import math
import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from endopipe.stages.camera import project
from endopipe.stages.nerf import losses
from endopipe.stages.nerf.bounds import PixelBounds, PriorBounds, target_bounds
from endopipe.stages.nerf.config import NerfConfig
from endopipe.stages.nerf.data import FrameSet, RaySampler, neighbours
from endopipe.stages.nerf.model import NerfModel
from endopipe.stages.nerf.pose_refine import PoseCorrection, corrected_world, lr_factor
from endopipe.stages.nerf.prior_depth import PriorRays
from endopipe.stages.nerf.proposal import ProposalGrid
from endopipe.stages.nerf.scene import SceneBox
from endopipe.stages.nerf.sdf_start import start_grid
from endopipe.stages.nerf.sparse_depth import SparseDepth

CHECKPOINT = "checkpoint.pt"
#: A batch's sampling bounds (near, far) when known beforehand; None: from the prior.
Bounds = tuple[Tensor, Tensor] | None
#: A pixel no brighter than this (display-encoded, its brightest channel) saw nothing: the
#: opacity loss asks no surface of its ray.
SEEN_LEVEL = 0.05
LOG_FIELDS = [
    "step",
    "loss",
    "photo",
    "prior",
    "core",
    "wall",
    "normal_var",
    "smooth",
    "geo",
    "distortion",
    "sparse",
    "stereo",
    "depth_prior",
    "eikonal",
    "pose_reg",
    "pose_deg",
    "pose_move",
    "psnr",
    "rays_per_s",
    "lr_grid",
    "elapsed_s",
]


def adam(groups: list[dict]) -> torch.optim.Adam:
    """The field's optimiser: Adam, fused where the device has the kernel (on a CPU ~10x
    faster than the loop over parameters for the grid's millions of entries)."""
    try:
        return torch.optim.Adam(groups, betas=(0.9, 0.99), fused=True)
    except (RuntimeError, TypeError, ValueError):
        return torch.optim.Adam(groups, betas=(0.9, 0.99))


def initial_gain(frames: FrameSet, train: list[int], pb: PriorBounds, gamma: float, gen) -> float:
    """Light gain so that a mid-grey albedo at the prior's wall matches the median pixel."""
    sampler = RaySampler(frames, train, 4096, 2, 0.0, gen)
    b = sampler.sample()
    o, d = frames.rays(b.frame, b.u, b.v)
    _, far, has = pb.bounds(o, d, 0.0, wall=True)
    r = (far * d.norm(dim=-1))[has] if has.any() else far * d.norm(dim=-1)
    if not has.any() and pb.typical_distance() is not None:  # no wall: the points' distance
        r = torch.full_like(r, pb.typical_distance())
    lin = b.rgb.mean(-1).clamp_min(1e-3) ** gamma
    # albedo ~0.5 and an average cos ~0.7: gain / r^2 * 0.35 = intensity
    return float(torch.median(lin).item() * torch.median(r.square()).item() / 0.35)


class Trainer:
    def __init__(
        self,
        cfg: NerfConfig,
        frames: FrameSet,
        train: list[int],
        prior,
        box: SceneBox,
        out_dir: Path,
        log: Callable[[str], None] = print,
        sparse: SparseDepth | None = None,
        refine_poses: bool = False,
        stereo: SparseDepth | None = None,
        prior_depth: PriorRays | None = None,
    ) -> None:
        self.cfg, self.frames, self.train_pos, self.box = cfg, frames, train, box
        self.sparse = sparse
        self.stereo = stereo
        self.prior_depth = prior_depth
        self.out_dir = Path(out_dir)
        self.log = log
        self.device = frames.device
        tc = cfg.train
        torch.manual_seed(tc.seed)
        self.gen = torch.Generator(device=self.device).manual_seed(tc.seed)
        self.pb = PriorBounds(prior, box, cfg)
        # The core L_prior keeps empty, no wider than the SfM points leave it.
        self.core_fraction = min(cfg.loss.core_fraction, prior.core_limit)
        gain = initial_gain(frames, train, self.pb, cfg.shading.gamma, self.gen)
        self.model = NerfModel(cfg, box, frames.n, gain=gain).to(self.device)
        self.model.set_trained_frames(train)
        if self.model.field.is_sdf:
            cams = frames.c2w[train, :3, 3]
            start = start_grid(self.pb, cams, cfg.field.sdf.start_nodes)
            self.model.field.start = start.to(self.device)
            wall = self.pb.prior.kind != "none"
            what = "the prior's wall" if wall else "spheres about the cameras"
            log(f"signed distance: a residual over {what}")
        # Pose corrections of every frame (held-out ones are fitted after training).
        self.correction: PoseCorrection | None = None
        if refine_poses:
            self.correction = PoseCorrection(frames.n, gauge=train).to(self.device)
        frames.correction, frames.refining = self.correction, False
        self._train_t = torch.as_tensor(train, dtype=torch.long, device=self.device)
        per_step = tc.frames_per_step if isinstance(tc.frames_per_step, int) else 0
        self.sampler = RaySampler(
            frames,
            train,
            tc.batch_rays,
            cfg.loss.patch_size,
            cfg.loss.patch_fraction,
            self.gen,
            frames_per_step=per_step,
        )
        if per_step > 0 and hasattr(self.model.field, "slice_times_up_to"):
            self.model.field.slice_times_up_to(per_step)
        # Poses that stay as given: every training pixel's ray bounds once, not each step.
        self.pixel_bounds = None if refine_poses else PixelBounds(self.pb, frames, train)
        fixed = sparse is not None and len(sparse) > 0 and not refine_poses
        self.sparse_bounds = target_bounds(self.pb, frames, sparse) if fixed else None
        nb = neighbours(train)
        table = torch.arange(frames.n, device=self.device)
        for k, v in nb.items():
            table[k] = v
        self.neighbour = table
        self.step_i = 0
        self.elapsed = 0.0
        self.rows: list[dict] = []
        sc = cfg.sampling
        if sc.proposal is not False and sc.sampler == "two_pass":  # auto unresolved: on
            self.model.proposal = ProposalGrid(tuple(box.extent), sc.proposal_res, self.device)
        self._build_optimizer()

    # --- optimiser ----------------------------------------------------------------------------
    def _build_optimizer(self) -> None:
        tc = self.cfg.train
        groups = self.model.param_groups(tc.lr_grid, tc.lr_mlp)
        if self.correction is not None:  # last: param_groups[0] stays the grid's
            lr = self.cfg.pose_refine.lr
            groups.append({"params": [self.correction.delta], "lr": lr, "name": "poses"})
        for g in groups:
            g["base_lr"] = g["lr"]
        self.opt = adam(groups)
        self._set_lr()

    @property
    def progress(self) -> float:
        """Training progress in [0, 1]: steps done, or the time budget used when that is
        further along. Every schedule (learning rate, upsampling, prior decay) follows it."""
        tc = self.cfg.train
        p = self.step_i / max(tc.steps, 1)
        if tc.time_budget_s:
            p = max(p, self.elapsed / tc.time_budget_s)
        return min(p, 1.0)

    def _set_lr(self) -> None:
        f = self.cfg.train.lr_decay**self.progress
        pc = self.cfg.pose_refine
        for g in self.opt.param_groups:
            g["lr"] = g["base_lr"] * f
            if g.get("name") == "poses":
                g["lr"] *= lr_factor(self.progress, pc.start, pc.warmup)

    # --- checkpoints --------------------------------------------------------------------------
    @property
    def ckpt_path(self) -> Path:
        return self.out_dir / CHECKPOINT

    @property
    def depth_supervised(self) -> bool:
        """Whether any measured depth trains the field (SfM points, stereo or given depth, a
        depth prior): those rays fit its expected depth."""
        lc = self.cfg.loss
        return any(
            rays is not None and len(rays) > 0 and weight > 0
            for rays, weight in (
                (self.sparse, lc.sparse_weight),
                (self.stereo, lc.stereo_weight),
                (self.prior_depth, self.prior_depth.weight if self.prior_depth else 0.0),
            )
        )

    def depth_sources(self) -> str:
        """What besides the images shaped the field's depth, in words (the fit's line)."""
        lc = self.cfg.loss
        parts = [
            name
            for name, used in (
                ("the SfM points", self.sparse is not None and lc.sparse_weight > 0),
                ("the stereo", self.stereo is not None and lc.stereo_weight > 0),
                ("the depth prior", self.prior_depth is not None and self.prior_depth.weight > 0),
                (f"the {self.pb.prior.kind} prior", self.pb.prior.kind != "none" and lc.prior),
            )
            if used
        ] or ["its smoothness alone"]
        return parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]

    def save_checkpoint(self) -> None:
        state = {
            "step": self.step_i,
            "elapsed": self.elapsed,
            "model": self.model.state_dict(),
            "opt": self.opt.state_dict(),
            "gen": self.gen.get_state(),
            "torch_rng": torch.get_rng_state(),
            "rows": self.rows,
        }
        if self.correction is not None:
            state["poses"] = self.correction.state_dict()
        if self.model.proposal is not None and self.model.proposal.ready:
            state["proposal"] = self.model.proposal.values
        self.out_dir.mkdir(parents=True, exist_ok=True)
        tmp = self.ckpt_path.with_suffix(".pt.tmp")
        torch.save(state, tmp)
        os.replace(tmp, self.ckpt_path)

    def try_resume(self) -> bool:
        if not self.ckpt_path.is_file():
            return False
        try:
            state = torch.load(self.ckpt_path, map_location=self.device, weights_only=False)
        except Exception as e:  # a corrupt checkpoint: start over rather than fail
            self.log(f"checkpoint unreadable ({type(e).__name__}); starting from scratch")
            return False
        self.model.load_state_dict(state["model"])
        if self.correction is not None and "poses" in state:
            self.correction.load_state_dict(state["poses"])
        proposal = self.model.proposal
        if proposal is not None and state.get("proposal") is not None:
            proposal.values = state["proposal"].to(self.device)
            proposal.ready = True
        self._build_optimizer()
        self.opt.load_state_dict(state["opt"])
        for g in self.opt.param_groups:  # base_lr is part of the saved groups
            g.setdefault("base_lr", g["lr"])
        self.gen.set_state(state["gen"])
        torch.set_rng_state(state["torch_rng"])
        self.step_i = int(state["step"])
        self.elapsed = float(state["elapsed"])
        self.rows = list(state["rows"])
        self._set_lr()
        return True

    # --- one step -----------------------------------------------------------------------------
    def step(self) -> dict[str, float]:
        cfg, lc = self.cfg, self.cfg.loss
        progress = self.progress
        renewed = self.model.field.on_progress(progress)
        if renewed:
            self.model.to(self.device)
            self._build_optimizer()
        self._refresh_proposal(everything=renewed)
        # Poses move once the coarse field has settled (before that: the given rays, exactly).
        self.frames.refining = self.correction is not None and (progress >= cfg.pose_refine.start)
        b = self.sampler.sample()
        o, d = self.frames.rays(b.frame, b.u, b.v)
        fixed = self.pixel_bounds if not self.frames.refining else None
        near, far = self.ray_bounds(o, d, b)
        warm = cfg.shading.normal_warmup
        mix = 1.0 if warm <= 0 else min(1.0, progress / warm)
        patches = b.n_patches * b.patch * b.patch
        need_normals = cfg.shading.tilt or (lc.prior and lc.normal_weight > 0 and b.n_patches > 0)
        out = self.model.render_rays(
            o,
            d,
            near,
            far,
            frame=b.frame,
            jitter=True,
            gen=self.gen,
            colour=True,
            normals=need_normals,
            shading_mix=mix,
        )
        terms: dict[str, torch.Tensor] = {}
        sat, trim = lc.saturation, lc.photo_trim
        photo = losses.photo(out["rgb"], b.rgb, b.valid, sat, trim)
        if "coarse_rgb" in out:
            photo = photo + losses.photo(out["coarse_rgb"], b.rgb, b.valid, sat, trim)
        terms["photo"] = photo
        loss = lc.photo_weight * photo if lc.photo else photo.detach() * 0
        if lc.prior and lc.lambda_prior > 0:
            lam = lc.lambda_prior * losses.prior_multiplier(
                progress, lc.prior_start, lc.prior_decay
            )
            prior = photo.new_zeros(())
            if lc.core_weight > 0 and self.core_fraction > 0:
                x = o[:, None, :] + out["t"][..., None] * d[:, None, :]
                inc = self.pb.in_core(x.reshape(-1, 3), self.core_fraction).view(out["t"].shape)
                # Only near the cameras: the tube follows the camera path, far ahead it is a
                # straight guess (scene units are lumen radii).
                inc = inc & (out["t"] * d.norm(dim=-1, keepdim=True) <= lc.core_reach)
                terms["core"] = losses.core_density(out["tau"], inc)
                prior = prior + lc.core_weight * terms["core"]
            if lc.wall_weight > 0:
                if fixed is not None:
                    wall, has_wall = fixed.wall_of(b.frame, b.u, b.v)
                else:
                    _, wall, has_wall = self.pb.bounds(o, d, 0.0, wall=True)
                terms["wall"] = losses.wall_attraction(
                    out["depth"], out["opacity"], wall, has_wall, lc.wall_tolerance
                )
                prior = prior + lc.wall_weight * terms["wall"]
            if lc.normal_weight > 0 and b.n_patches > 0 and "normal" in out:
                n = out["normal"][:patches].view(b.n_patches, b.patch * b.patch, 3)
                terms["normal_var"] = losses.normal_variance(n)
                prior = prior + lc.normal_weight * terms["normal_var"]
            terms["prior"] = prior
            loss = loss + lam * prior
        if lc.smooth and lc.lambda_smooth > 0 and b.n_patches > 0:
            p = b.patch
            z = out["depth"][:patches].view(b.n_patches, p, p)
            img = b.rgb[:patches].view(b.n_patches, p, p, 3)
            terms["smooth"] = losses.edge_aware_smoothness(z, img, lc.smooth_order, lc.edge_scale)
            loss = loss + lc.lambda_smooth * terms["smooth"]
        if lc.geo and lc.lambda_geo > 0 and b.n_patches > 0 and lc.geo_patches > 0:
            terms["geo"] = self._geo_term(b, o, d, out["depth"])
            loss = loss + lc.lambda_geo * terms["geo"]
        if lc.sparse_weight > 0 and self.sparse is not None:
            terms["sparse"] = self._sparse_term()
            loss = loss + lc.sparse_weight * terms["sparse"]
        if lc.stereo_weight > 0 and self.stereo is not None:
            frame, u, v, z = self.stereo.sample(lc.stereo_rays, self.gen)
            rendered = self._render(*self.frames.rays(frame, u, v), frame)
            terms["stereo"] = losses.sparse_depth(rendered["depth"], z)
            loss = loss + lc.stereo_weight * terms["stereo"]
            spread = lc.spread_weight(still=False)  # set_up_training resolved auto
            if spread > 0:
                terms["stereo_spread"] = losses.depth_spread(rendered["t"], rendered["weights"], z)
                loss = loss + spread * terms["stereo_spread"]
        if self.prior_depth is not None and self.prior_depth.weight > 0:
            n, r = lc.depth_prior_frames, lc.depth_prior_rays
            frame, u, v, p = self.prior_depth.sample(n, r, self.gen)
            depth = self._depth(*self.frames.rays(frame, u, v), frame)
            terms["depth_prior"] = losses.prior_depth(depth.view(n, r), p.view(n, r))
            loss = loss + self.prior_depth.weight * terms["depth_prior"]
        if lc.opacity_weight > 0 and self.pb.prior.kind == "none":
            # A scope sees tissue along every ray, within its reach; a lumen prior asks that of
            # the rays that meet its wall already (the wall term), and none of those down it.
            # A black pixel saw nothing (outside the lens, beyond the light): no target there.
            seen = b.rgb.amax(dim=-1) > SEEN_LEVEL
            valid = (b.valid & seen).float()
            gap = (1.0 - out["opacity"]).clamp_min(0).square()
            terms["opacity"] = (gap * valid).sum() / valid.sum().clamp_min(1.0)
            loss = loss + lc.opacity_weight * terms["opacity"]
        if lc.distortion_weight > 0:
            terms["distortion"] = losses.distortion(out["t"], out["weights"], far)
            loss = loss + lc.distortion_weight * terms["distortion"]
        if self.frames.refining and cfg.pose_refine.l2 > 0:
            assert self.correction is not None
            terms["pose_reg"] = self.correction.penalty(self._train_t)
            loss = loss + cfg.pose_refine.l2 * terms["pose_reg"]
        if self.model.field.is_sdf and cfg.field.sdf.eikonal_weight > 0:
            terms["eikonal"] = self._eikonal_term(o, d, near, far)
            loss = loss + cfg.field.sdf.eikonal_weight * terms["eikonal"]
        extra = self.model.field.extra_loss()
        if extra is not None:
            loss = loss + extra
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        self.opt.step()
        self.step_i += 1
        self._set_lr()
        # Tensors, not floats: reading a value waits for the device, so on a GPU the log reads
        # them once every log_every steps and the steps between queue without waiting.
        vals = {k: v.detach() for k, v in terms.items()}
        vals["loss"] = loss.detach()
        if self.correction is not None:
            delta = self.correction.effective().detach()[self._train_t]
            vals["pose_deg"] = delta[:, :3].norm(dim=-1).mean() * (180.0 / math.pi)
            vals["pose_move"] = delta[:, 3:].norm(dim=-1).mean() * self.box.scale
        return vals

    def ray_bounds(self, o: torch.Tensor, d: torch.Tensor, b) -> tuple[torch.Tensor, torch.Tensor]:
        """A batch's near and far bounds: each pixel's, found once, while the poses stay as
        given; else from the prior along the rays as they are now."""
        fixed = self.pixel_bounds if not self.frames.refining else None
        if fixed is not None:
            return fixed.sampling(b.frame, b.u, b.v)
        near, far, _ = self.pb.bounds(o, d, self.pb.margin)
        return near, far

    def _refresh_proposal(self, everything: bool) -> None:
        """Refresh the proposal grid: all of it at the start and when the field's parameters
        were replaced, a share of it every `proposal_every` steps."""
        p, sc = self.model.proposal, self.cfg.sampling
        if p is None:
            return
        if everything or not p.ready:
            share = 1.0
        elif self.step_i % sc.proposal_every == 0:
            share = sc.proposal_share
        else:
            return
        field = self.model.field
        if field.dynamic:  # the densest the scene is at any time: a random time a point

            def density(g: torch.Tensor) -> torch.Tensor:
                t = torch.rand(g.shape[0], 1, device=g.device, generator=self.gen) * 2 - 1
                return field.density(torch.cat([g, t], -1))
        else:
            density = field.density
        p.refresh(density, share, self.gen)

    def _eikonal_term(self, o, d, near, far) -> torch.Tensor:
        """The eikonal term at random points between the batch's near and far bounds (free
        space, the wall and behind it alike)."""
        n = self.cfg.field.sdf.eikonal_points
        i = torch.randint(0, o.shape[0], (n,), device=o.device, generator=self.gen)
        u = torch.rand(n, device=o.device, generator=self.gen)
        t = near[i] + u * (far[i] - near[i])
        return self.model.eikonal(o[i] + t[:, None] * d[i])

    def _sparse_term(self) -> torch.Tensor:
        """Rendered depth against the SfM points' depth on a random draw of tracked pixels."""
        assert self.sparse is not None
        sp, k = self.sparse, self.sparse.draw(self.cfg.loss.sparse_rays, self.gen)
        o, d = self.frames.rays(sp.frame[k], sp.u[k], sp.v[k])
        fixed = self.sparse_bounds if not self.frames.refining else None
        bounds = None if fixed is None else (fixed[0][k], fixed[1][k])
        return losses.sparse_depth(self._depth(o, d, sp.frame[k], bounds), sp.z[k])

    def _depth(
        self, o: Tensor, d: Tensor, frame: Tensor | None = None, bounds: Bounds = None
    ) -> torch.Tensor:
        """Rendered depth of extra rays (density only, jittered, with gradients), at their
        frames' time (a dynamic field); `bounds` (near, far) when known, else from the prior."""
        return self._render(o, d, frame, bounds)["depth"]

    def _render(
        self, o: Tensor, d: Tensor, frame: Tensor | None = None, bounds: Bounds = None
    ) -> dict[str, torch.Tensor]:
        """`_depth`'s render, with its samples' depths and weights."""
        near, far = bounds if bounds is not None else self.pb.bounds(o, d, self.pb.margin)[:2]
        return self.model.render_rays(
            o, d, near, far, frame=frame, jitter=True, gen=self.gen, colour=False, normals=False
        )

    def _geo_term(self, b, o, d, depth) -> torch.Tensor:
        """Warp frame t's rendered depth into its neighbour and compare with the depth rendered
        there (seed §3.4)."""
        n = min(self.cfg.loss.geo_patches, b.n_patches) * b.patch * b.patch
        x = o[:n] + depth[:n, None] * d[:n]
        nb = self.neighbour[b.frame[:n]]
        c2w = self.frames.pose(nb)
        uv, zc = project(self.frames.camera, x, c2w, near=1e-4)
        u, v = uv[:, 0], uv[:, 1]
        h, w = self.frames.h, self.frames.w
        inside = (zc > 1e-3) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
        ui = u.detach().round().long().clamp(0, w - 1)
        vi = v.detach().round().long().clamp(0, h - 1)
        valid = inside & self.frames.masks[nb, vi, ui]
        o2, d2 = self.frames.pixel_rays(c2w, u.detach(), v.detach())
        return losses.geometric_consistency(zc, self._depth(o2, d2, nb), valid)

    # --- poses ------------------------------------------------------------------------------------
    def refine_heldout(self, held: list[int]) -> bool:
        """Fit the held-out frames' corrections to their images with the field frozen (test-time
        pose optimisation), so their PSNR measures the field, not the given poses' error.
        Returns whether it ran."""
        pc, lc = self.cfg.pose_refine, self.cfg.loss
        if self.correction is None or not held or pc.heldout_steps <= 0:
            return False
        sampler = RaySampler(self.frames, held, pc.heldout_rays, 2, 0.0, self.gen)
        held_t = torch.as_tensor(held, dtype=torch.long, device=self.device)
        others = torch.ones(self.frames.n, dtype=torch.bool, device=self.device)
        others[held_t] = False
        delta = self.correction.delta
        opt = torch.optim.Adam([delta], lr=pc.lr, betas=(0.9, 0.99))
        frozen = [(p, p.requires_grad) for p in self.model.parameters()]
        for p, _ in frozen:
            p.requires_grad_(False)
        self.frames.refining = True
        try:
            for _ in range(pc.heldout_steps):
                b = sampler.sample()
                o, d = self.frames.rays(b.frame, b.u, b.v)
                near, far, _ = self.pb.bounds(o, d, self.pb.margin)
                out = self.model.render_rays(
                    o, d, near, far, frame=b.frame, jitter=True, gen=self.gen, colour=True
                )
                loss = losses.photo(out["rgb"], b.rgb, b.valid, lc.saturation, lc.photo_trim)
                loss = loss + pc.l2 * self.correction.penalty(held_t)
                opt.zero_grad(set_to_none=True)
                loss.backward()
                delta.grad[others] = 0.0  # the training frames' corrections stay as trained
                opt.step()
        finally:
            for p, flag in frozen:
                p.requires_grad_(flag)
        return True

    def world_poses(self, c2w_world: list[np.ndarray]) -> list[np.ndarray]:
        """The frames' given world poses with their corrections (as given without any)."""
        if self.correction is None:
            return [np.asarray(c, np.float64) for c in c2w_world]
        delta = self.correction.effective().detach().double().cpu().numpy()
        return corrected_world(c2w_world, delta, self.box)

    # --- the loop -----------------------------------------------------------------------------
    def fit(self, advance: Callable[..., None] | None = None) -> None:
        tc = self.cfg.train
        if self.step_i and advance is not None:
            advance(self.step_i, info="resumed")
        window_rays, window_t = 0, 0.0
        acc: dict[str, list[torch.Tensor]] = {}
        while self.step_i < tc.steps and self.progress < 1.0:
            t0 = time.perf_counter()
            vals = self.step()
            for k, v in vals.items():
                acc.setdefault(k, []).append(v)
            window_rays += tc.batch_rays
            done = self.step_i >= tc.steps or self.progress >= 1.0
            logging = self.step_i % tc.log_every == 0 or done
            if logging:
                row = self._window_means(acc)  # waits for the queued steps
            dt = time.perf_counter() - t0
            self.elapsed += dt
            window_t += dt
            if logging:
                row.update(
                    step=self.step_i,
                    psnr=losses.psnr(row.get("photo", 0.0)),
                    rays_per_s=window_rays / max(window_t, 1e-9),
                    lr_grid=self.opt.param_groups[0]["lr"],
                    elapsed_s=self.elapsed,
                )
                self.rows.append(row)
                acc, window_rays, window_t = {}, 0, 0.0
                if advance is not None:
                    advance(
                        0,
                        info=f"loss {row['loss']:.4f}  PSNR {row['psnr']:.1f}  "
                        f"{row['rays_per_s']:.0f} rays/s",
                    )
            if advance is not None:
                advance(1)
            if self.step_i % tc.checkpoint_every == 0 and not done:
                self.save_checkpoint()

    def _window_means(self, acc: dict[str, list[torch.Tensor]]) -> dict[str, float]:
        """The logged window's mean of each term; a loss gone non-finite stops training with
        the step where it did."""
        loss = torch.stack(acc["loss"]).cpu()
        finite = torch.isfinite(loss)
        if not bool(finite.all()):
            bad = self.step_i - len(loss) + 1 + int((~finite).nonzero()[0])
            raise FloatingPointError(f"nerf loss is {float(loss[~finite][0])} at step {bad}")
        return {k: float(torch.stack(v).float().mean()) for k, v in acc.items()}

    def write_log(self, path: Path) -> None:
        with open(path, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=LOG_FIELDS, extrasaction="ignore")
            w.writeheader()
            for r in self.rows:
                w.writerow({k: r.get(k, "") for k in LOG_FIELDS})
