"""The albedo fitted again with the geometry fixed, when a colour channel's albedo sat at its
ceiling after training.

Why: the near light explains a pixel's brightness by its distance and tilt, the albedo by the
rest. On footage from a red scope (the C3VD colon) the red channel's albedo ends training at the
sigmoid's ceiling on every pixel: red is all shading. That is the shading cue the depth rests on
(with the red albedo free from the start the training fit rose 6 dB and the depth ranked 0.92
instead of 0.97: docs/results.md, "Real footage"), but it leaves the field unable to render
what it saw (a training fit of 23 dB, dark blotches down the lumen). So the geometry trains as
it does, and then the albedo alone is fitted again under a light bright enough that the pinned
channel's pixels ask for about half its ceiling: the density, the poses and the exposures stay as
trained, so the depth is the same to the bit, and the renders are the images'.

With the geometry fixed, all that a step would recompute but the albedo is the same every step:
a pool of training rays is rendered once, as frames are rendered (the evaluation's samples, not
training's jittered ones), and each step reads only the albedo at the samples that count. On
C3VD that was 61 s against 100 for the same 600 steps through the training step, and the renders
rose 2.3 dB more (held-out 31.0 dB against 28.8): the albedo is fitted under the renderer that
renders it.
"""

from __future__ import annotations

import math
import time

import torch

from endopipe.stages.nerf import losses
from endopipe.stages.nerf.data import RaySampler
from endopipe.stages.nerf.summary import CHANNELS, ColourRefit
from endopipe.stages.nerf.train import adam

#: An albedo over this is at the sigmoid's ceiling (its gradient nearly gone).
CEILING = 0.95
#: Rays drawn from the training frames to measure it.
PROBE_RAYS = 4096
#: A pixel this bright or brighter is saturated: it asks for no particular albedo.
SATURATED = 0.98
#: The refit's learning rates, in the schedule's first ones: the decoder's output for a pinned
#: channel starts deep in the sigmoid's saturation (C3VD: at 1x, 600 steps left red at the
#: ceiling and the render 4 dB worse; at 10x, held-out 28.4 dB from 24.1, both through the
#: training step; on the pool at 10x, 31.0 dB).
REFIT_LR = 10.0
#: While the albedo is fitted again, the light is made bright enough that the pinned channel's
#: median pixel asks for this albedo.
ROOM = 0.5


def can_refit(model) -> bool:
    """Only a grid field with a separate albedo grid and colour decoder (TensoRF's) is split so."""
    return all(hasattr(model.field, a) for a in ("app_grid", "basis", "color"))


@torch.no_grad()
def albedo_probe(trainer, seed: int = 0) -> tuple[list[float], list[float]]:
    """Per colour channel, over a draw of training rays (opaque, usable): the share whose albedo,
    composited and divided by the opacity, is over CEILING; and over those of them whose pixel
    is not saturated, the median albedo the pixel asks for in units of that albedo (its value
    over the render's, linearised by the field's gamma): how much brighter the light must be to
    leave the channel room. Its own generator: the trainer's draws stay as they were."""
    gen = torch.Generator(device=trainer.device).manual_seed(seed)
    sampler = RaySampler(trainer.frames, trainer.train_pos, PROBE_RAYS, 2, 0.0, gen)
    b = sampler.sample()
    o, d = trainer.frames.rays(b.frame, b.u, b.v)
    near, far = trainer.ray_bounds(o, d, b)
    model = trainer.model
    was_training = model.training
    model.eval()
    try:
        out = model.render_rays(o, d, near, far, frame=b.frame, colour=True)
    finally:
        model.train(was_training)
    opacity = out["opacity"]
    seen = b.valid & (opacity > 0.5)
    if not seen.any():
        return [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]
    albedo = out["albedo"][seen] / opacity[seen, None]
    asks = (b.rgb[seen] / out["rgb"][seen].clamp_min(1e-4)) ** float(model.gamma())
    shares, needs = [], []
    for c in range(3):
        at = albedo[:, c] > CEILING
        shares.append(round(float(at.float().mean()), 4))
        fair = at & (b.rgb[seen][:, c] < SATURATED)
        needs.append(round(float(asks[fair, c].median()), 3) if fair.any() else 1.0)
    return shares, needs


def refit_if_pinned(trainer, log, progress) -> ColourRefit | None:
    """Measure the albedo's ceiling after training and, when a channel sits there on more than
    `train.colour_ceiling` of the rays, fit the albedo again (`train.colour_steps`); `progress`
    is the stage's progress bar (a context manager giving `advance`). None: not measured (off,
    or a field that keeps no separate albedo)."""
    tc = trainer.cfg.train
    if tc.colour_steps <= 0 or not can_refit(trainer.model):
        return None
    share, asks = albedo_probe(trainer)
    pinned = max(range(3), key=share.__getitem__)
    if share[pinned] <= tc.colour_ceiling:
        return ColourRefit(ceiling=share)
    brighter = max(asks[pinned], 1.0) / ROOM
    log(
        f"the {CHANNELS[pinned]} channel's albedo sat at its ceiling on {share[pinned]:.0%} of the "
        f"training rays (its brightness all shading; its pixels ask for {asks[pinned]:.2f} of "
        f"it): {tc.colour_steps} steps fit the albedo again with the geometry fixed, the light "
        f"x{brighter:.2f} (nerf.train.colour_steps)"
    )
    with progress("albedo", total=tc.colour_steps) as advance:
        seconds = refit_albedo(trainer, tc.colour_steps, brighter, advance)
    return ColourRefit(
        ceiling=share,
        asked=asks,
        light_factor=round(brighter, 3),
        steps=tc.colour_steps,
        seconds=round(seconds, 1),
        ceiling_after=albedo_probe(trainer)[0],
    )


#: Rays the refit's pool holds at most (drawn once, rendered once through the fixed geometry);
#: its batches cycle through it when `colour_steps` x the batch is more.
POOL_RAYS = 2**18
#: Rays rendered at a time while the pool is drawn.
POOL_CHUNK = 4096


class _Pool:
    """Training rays rendered once through the fixed geometry: per ray what shades it (its
    direction, frame, depth, opacity, normal) and its pixel; per sample that counts (compositing
    weight over WEIGHT_FLOOR) its grid point, weight and ray, ray-major, so that a batch of
    consecutive rays reads one slice of samples. Why: with the density, the poses and the
    exposures fixed, everything a step would recompute but the albedo is the same every step."""

    def __init__(self, trainer, rays: int, seed: int) -> None:
        gen = torch.Generator(device=trainer.device).manual_seed(seed)
        sampler = RaySampler(trainer.frames, trainer.train_pos, POOL_CHUNK, 2, 0.0, gen)
        model = trainer.model
        per_ray: dict[str, list[torch.Tensor]] = {}
        points, weights, of_ray = [], [], []
        drawn = 0
        was_training = model.training
        model.eval()
        try:
            with torch.no_grad():
                while drawn < rays:
                    b = sampler.sample()  # single rays, every one inside the usable mask
                    o, d = trainer.frames.rays(b.frame, b.u, b.v)
                    near, far = trainer.ray_bounds(o, d, b)
                    out = model.render_rays(o, d, near, far, frame=b.frame, colour=True)
                    parts = {"frame": b.frame, "d": d, "dnorm": d.norm(dim=-1), "rgb": b.rgb}
                    for k in ("depth", "opacity", "normal"):
                        if k in out:
                            parts[k] = out[k]
                    for k, t in parts.items():
                        per_ray.setdefault(k, []).append(t)
                    kept = out["kept"]
                    points.append(out["points"][kept])
                    weights.append(out["weights"].reshape(-1)[kept])
                    of_ray.append(kept // out["t"].shape[1] + drawn)
                    drawn += len(b.frame)
        finally:
            model.train(was_training)
        self.rays = {k: torch.cat(v)[:rays] for k, v in per_ray.items()}
        ray = torch.cat(of_ray)
        inside = ray < rays
        self.points = torch.cat(points)[inside]
        self.weights = torch.cat(weights)[inside]
        self.ray = ray[inside]
        counts = torch.bincount(self.ray, minlength=rays)
        self.start = torch.cat([counts.new_zeros(1), torch.cumsum(counts, 0)])

    def __len__(self) -> int:
        return len(self.rays["frame"])

    def batch(self, lo: int, hi: int) -> tuple[dict[str, torch.Tensor], slice]:
        """Rays lo..hi-1 and the slice of their samples."""
        return {k: v[lo:hi] for k, v in self.rays.items()}, slice(
            int(self.start[lo]), int(self.start[hi])
        )


def refit_albedo(trainer, steps: int, brighter: float, advance=None) -> float:
    """`steps` steps that move only the albedo grid, the colour decoder and the ambient light,
    under the light's gain times `brighter` (fixed), at REFIT_LR times the schedule's first
    learning rates, on a pool of training rays rendered once through the fixed geometry (the
    photometric loss alone: every other term is the geometry's). The trainer's parameters other
    than those, its step count and its optimiser are as they were. Returns the seconds."""
    model, tc, lc = trainer.model, trainer.cfg.train, trainer.cfg.loss
    field = model.field
    grid = list(field.app_grid.parameters())
    decoder = [*field.basis.parameters(), *field.color.parameters()]
    free = {id(p) for p in (*grid, *decoder, model.ambient_raw)}
    trained = {p: p.requires_grad for p in model.parameters()}
    t0 = time.perf_counter()
    batch = tc.batch_rays
    pool = _Pool(trainer, min(steps * batch, POOL_RAYS), tc.seed)
    for p in model.parameters():
        p.requires_grad_(id(p) in free)
    with torch.no_grad():
        model.log_gain += math.log(brighter)
    optimiser = adam(
        [
            {"params": grid, "lr": REFIT_LR * tc.lr_grid},
            {"params": [*decoder, model.ambient_raw], "lr": REFIT_LR * tc.lr_mlp},
        ]
    )
    batches = max(len(pool) // batch, 1)
    # every batch is this long, and every ray of the pool usable
    usable = torch.ones(min(batch, len(pool)), dtype=torch.bool, device=trainer.device)
    try:
        for i in range(steps):
            lo = (i % batches) * batch
            rays, samples = pool.batch(lo, min(lo + batch, len(pool)))
            feat = field.app_grid(pool.points[samples])
            d = rays["d"]
            albedo = model.albedo_of(
                feat, pool.weights[samples], pool.ray[samples] - lo, rays["opacity"], d
            )
            rgb = model.shade(rays, albedo, d, rays["dnorm"], rays["frame"], 1.0)
            loss = lc.photo_weight * losses.photo(
                rgb, rays["rgb"], usable, lc.saturation, lc.photo_trim
            )
            extra = field.albedo_loss()
            if extra is not None:
                loss = loss + extra
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            if advance is not None:
                advance(1)
    finally:
        for p, on in trained.items():
            p.requires_grad_(on)
    return time.perf_counter() - t0
