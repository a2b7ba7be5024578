"""The NeRF model: a field in a scene box, the sampler, compositing and the near-light shading.

Rays live in the scene frame (see scene.py) with directions whose camera-frame z is 1, so every
depth `t` here is a z-depth in scene units (world z-depth = t * box.scale).

Shading (seed §3.2) is deferred to the ray's expected surface point: the composited albedo is lit
by gain * max(n.l, 0) / r^2 + ambient, with the light at the camera centre (l = -ray direction),
r the distance to the expected surface and n the normalised negative density gradient there
(central finite differences of `field.density`, so any encoding works and no double backward is
needed). Frames are display-encoded: colour^(1/gamma), gamma fixed or learned.

The scope's photometry (each piece optional, `ShadingConfig`): a per-frame exposure (log gain,
zero-mean over the training frames, so held-out frames, which have none, get the mean) and a
radial falloff F(theta) = exp(sum_k a_k (1 - cos theta)^k) of the ray's angle theta to the
optical axis. With the light at the camera centre and symmetric about the axis, the light's
emission angle is theta too, so its angular profile and the lens's vignetting cannot be told
apart: F is both. cos theta = 1 / |d|: every ray direction has camera-frame z = 1 with the lens
undone (camera.rays.pixel_directions), and poses and the scene frame only rotate directions.
A view that does not carry the light (a rectified rig's right eye, lit from the left) is
shaded from the light's own pose instead (`render_rays(light=...)`).
"""

from __future__ import annotations

import math
from contextlib import contextmanager

import torch
from torch import nn

from endopipe.stages.nerf.config import NerfConfig
from endopipe.stages.nerf.field import RadianceField, make_field
from endopipe.stages.nerf.proposal import ProposalGrid
from endopipe.stages.nerf.sampling import coarse_then_fine, composite, spaced, two_pass
from endopipe.stages.nerf.scene import SceneBox

#: Samples whose compositing weight is at most this add nothing a pixel shows: a deferred
#: field reads no albedo features there (most samples of a ray that meets one surface).
WEIGHT_FLOOR = 1e-4
#: Terms of the radial falloff polynomial in (1 - cos theta).
FALLOFF_TERMS = 3


#: Entries of the state dict added after model.pt files were first written.
NEW_KEYS = (
    "exposure_trained",
    "falloff",
    "log_gamma",
    "field.beta",
    "field.start",
    "frame_time",
)


class NerfModel(nn.Module):
    def __init__(self, cfg: NerfConfig, box: SceneBox, n_frames: int, gain: float = 1.0) -> None:
        super().__init__()
        self.cfg = cfg
        self.box = box
        self.field: RadianceField = make_field(cfg.field, tuple(box.extent))
        self.log_gain = nn.Parameter(torch.tensor(math.log(gain)), requires_grad=True)
        amb = max(cfg.shading.ambient, 1e-6)
        self.ambient_raw = nn.Parameter(torch.tensor(math.log(math.expm1(amb))))
        # Log gains per frame and colour channel (the exposure and the white balance).
        self.exposure = nn.Parameter(torch.zeros(max(n_frames, 1), 3))
        # Which frames' exposures are trained: the gauge (their mean is 0), set by the trainer.
        self.register_buffer("exposure_trained", torch.ones(max(n_frames, 1)))
        self.falloff = nn.Parameter(torch.zeros(FALLOFF_TERMS))  # a_k: F = 1 at the start
        self.log_gamma = nn.Parameter(torch.tensor(math.log(cfg.shading.gamma)))
        # A dynamic field's time of each frame (by position), in [-1, 1]; `_time` the rays'
        # (or one for all) while rendering: `to_grid` appends it to every point.
        self.register_buffer("frame_time", torch.zeros(max(n_frames, 1)))
        self._time: torch.Tensor | None = None
        # The trainer's coarse copy of the density (proposal.py), read by the first sampling
        # pass while training; None, or not ready: the field itself. Not part of the model.
        self.proposal: ProposalGrid | None = None

    def set_trained_frames(self, frames: list[int]) -> None:
        """Only these frames' exposures are fitted (and define their zero mean)."""
        mask = torch.zeros_like(self.exposure_trained)
        mask[torch.as_tensor(frames, dtype=torch.long)] = 1.0
        self.exposure_trained.copy_(mask)

    def load_state_dict(self, state, strict: bool = True, assign: bool = False):  # type: ignore
        """Also restores a TensoRF grid's resolution (it changes while training); parameters
        newer than the state dict (the photometric model) keep their initial values."""
        own = super().state_dict()
        state = {**{k: own[k] for k in NEW_KEYS if k not in state}, **state}
        if state["exposure"].dim() == 1:  # one log gain a frame, before the colour channels
            state = {**state, "exposure": state["exposure"][:, None].expand(-1, 3).clone()}
        start = state.get("field.start")
        if start is not None and hasattr(self.field, "start"):
            self.field.start = start.to(self.log_gain.device)
        res = state.get("field.res_now")
        if res is not None and hasattr(self.field, "set_resolution"):
            res = tuple(int(v) for v in res)
            if res != tuple(self.field.density_grid.res):
                device = self.log_gain.device
                self.field.set_resolution(res)
                self.field.to(device)
        return super().load_state_dict(state, strict=strict, assign=assign)

    # --- parameters -------------------------------------------------------------------------
    def param_groups(self, lr_grid: float, lr_mlp: float) -> list[dict]:
        groups = self.field.param_groups(lr_grid, lr_mlp)
        sc = self.cfg.shading
        shade = [self.ambient_raw]
        if sc.learn_gain:
            shade.append(self.log_gain)
        groups.append({"params": shade, "lr": lr_mlp, "name": "shading"})
        photometric = [
            p
            for p, on in (
                (self.exposure, sc.exposure),
                (self.falloff, sc.falloff == "learned"),
                (self.log_gamma, sc.learn_gamma),
            )
            if on
        ]
        if photometric:
            groups.append({"params": photometric, "lr": sc.lr, "name": "photometric"})
        return groups

    def photometry(self) -> dict[str, float | list[float]]:
        """The fitted photometric model, for summaries: gamma, falloff a_k, F at 30 and 60
        degrees off the axis, spread of the log exposures."""
        sc = self.cfg.shading
        with torch.no_grad():
            out: dict[str, float | list[float]] = {"gamma": float(self.gamma())}
            if sc.falloff == "learned":
                out["falloff"] = [float(a) for a in self.falloff]
                for deg in (30, 60):
                    c = torch.tensor([math.cos(math.radians(deg))], device=self.falloff.device)
                    out[f"falloff_{deg}deg"] = float(self.radial_falloff(c)[0])
            if sc.exposure is True:
                keep = self.exposure_trained > 0
                out["exposure_std"] = float(
                    self._exposure_centred()[keep].mean(-1).std(unbiased=False)
                )
            return out

    # --- geometry helpers ---------------------------------------------------------------------
    def to_grid(self, x: torch.Tensor) -> torch.Tensor:
        """Grid coordinates of scene points; a dynamic field's get their time as a fourth
        column: the rays' being rendered (points ray-major, each ray's together), else the one
        set by `at_frame`, else the first frame's."""
        g = self.box.to_grid(x)
        if not self.field.timed:
            return g
        flat = g.reshape(-1, 3)
        t = self._time if self._time is not None else self.frame_time[:1]
        if t.numel() == 1:
            tt = t.reshape(1).expand(flat.shape[0])
        else:
            if flat.shape[0] % t.shape[0]:
                raise ValueError("points of a dynamic field must be ray-major, whole rays")
            tt = t.repeat_interleave(flat.shape[0] // t.shape[0])
        return torch.cat([flat, tt[:, None].to(flat.dtype)], -1).reshape(*g.shape[:-1], 4)

    def set_frame_times(self, times: list[float]) -> None:
        """Each frame's time (by position; seconds or any increasing number), mapped to [-1, 1]."""
        t = torch.as_tensor(times, dtype=torch.float64)
        span = float(t.max() - t.min()) if len(t) > 1 else 0.0
        scaled = 2.0 * (t - t.min()) / span - 1.0 if span > 0 else torch.zeros_like(t)
        self.frame_time.copy_(scaled.to(self.frame_time))

    @contextmanager
    def at_frame(self, frame: int | None):
        """Render (depth, density grids, meshes) at frame `frame`'s time (by position)."""
        before = self._time
        if frame is not None:
            self._time = self.frame_time[frame : frame + 1]
        try:
            yield self
        finally:
            self._time = before

    def density_scene(self, x: torch.Tensor) -> torch.Tensor:
        """sigma at scene points (M, 3)."""
        return self.field.density(self.to_grid(x))

    def signed_distance_scene(self, x: torch.Tensor) -> torch.Tensor:
        """d at scene points (M, 3), positive in free space (signed-distance geometry)."""
        return self.field.signed_distance(self.to_grid(x))

    def _central_differences(self, fn, x: torch.Tensor, h: float) -> torch.Tensor:
        """(fn(x + h e_i) - fn(x - h e_i)) / 2h for i = x, y, z: (M, 3)."""
        eye = torch.eye(3, device=x.device, dtype=x.dtype) * h
        pts = torch.cat([x[:, None, :] + eye, x[:, None, :] - eye], 1).reshape(-1, 3)
        s = fn(pts).view(-1, 2, 3)
        return (s[:, 0] - s[:, 1]) / (2.0 * h)

    def normals(self, x: torch.Tensor) -> torch.Tensor:
        """Unit normals at scene points (B, 3), pointing into free space: -grad sigma, or grad d
        for a signed distance (defined off the surface too, where sigma underflows); central
        differences with a step of `normal_eps` grid cells (cells of the unwarped core)."""
        x = x.detach()
        h = self.cfg.shading.normal_eps * self.field.cell * 0.5 * float(self.box.extent.max())
        if self.field.is_sdf:
            grad = self._central_differences(self.signed_distance_scene, x, h)
        else:
            grad = -self._central_differences(self.density_scene, x, h)
        return grad / grad.norm(dim=-1, keepdim=True).clamp_min(1e-6)

    def eikonal(self, x: torch.Tensor) -> torch.Tensor:
        """(|grad d| - 1)^2 at scene points, averaged: d stays a distance (one grid cell
        differences, so no double backward through the grid)."""
        h = self.field.cell * 0.5 * float(self.box.extent.max())
        grad = self._central_differences(self.signed_distance_scene, x.detach(), h)
        return (grad.norm(dim=-1) - 1.0).square().mean()

    # --- sampling -----------------------------------------------------------------------------
    def sample(self, o, d, near, far, jitter: bool, gen=None) -> torch.Tensor:
        s = self.cfg.sampling
        if s.sampler == "two_pass":
            # Rendering needs fewer samples than training: the weights are settled by then.
            n_coarse, n_fine, n_uniform = (
                (s.n_coarse, s.n_fine, s.n_uniform)
                if self.training
                else (s.render_coarse, s.render_fine, 0)
            )
            return two_pass(
                self._first_pass_density(),
                o,
                d,
                near,
                far,
                n_coarse,
                n_fine,
                n_uniform,
                s.spacing,
                jitter,
                gen,
            )
        return spaced(near, far, s.n_coarse, s.spacing, jitter, gen)

    def _first_pass_density(self):
        """What the first sampling pass reads: the proposal grid in training once it holds the
        field, else the field."""
        p = self.proposal
        if self.training and p is not None and p.ready:
            return lambda x: p.density(self.box.to_grid(x))
        return self.density_scene

    # --- rendering ----------------------------------------------------------------------------
    def render_rays(
        self,
        o: torch.Tensor,
        d: torch.Tensor,
        near: torch.Tensor,
        far: torch.Tensor,
        *,
        frame: torch.Tensor | None = None,
        jitter: bool = False,
        gen: torch.Generator | None = None,
        colour: bool = True,
        normals: bool | None = None,
        shading_mix: float = 1.0,
        light: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        """Render rays (scene frame). Returns depth (z, scene units), opacity, and when `colour`:
        rgb (display-encoded), plus normal/cos when computed, the samples t and weights.
        `light`: the scope's light as a camera pose in the scene frame (4x4: its centre holds
        the light, its z axis is the light's axis), for an eye that does not carry it (a
        rectified rig's right eye is lit from the left); None: at each ray's origin."""
        before = self._time
        if self.field.timed and frame is not None:
            self._time = self.frame_time[frame]
        try:
            return self._render_rays(
                o, d, near, far, frame, jitter, gen, colour, normals, shading_mix, light
            )
        finally:
            self._time = before

    def _render_rays(
        self, o, d, near, far, frame, jitter, gen, colour, normals, shading_mix, light
    ):
        dnorm = d.norm(dim=-1)
        t = self.sample(o, d, near, far, jitter, gen)
        out = self._composite(o, d, t, dnorm, far, colour)
        if self.cfg.sampling.sampler == "coarse_fine":
            coarse = out
            t = coarse_then_fine(t, coarse["weights"], self.cfg.sampling.n_fine, jitter, gen)
            out = self._composite(o, d, t, dnorm, far, colour)
            out["coarse_rgb_albedo"] = coarse["albedo"] if colour else None
            out["coarse_depth"] = coarse["depth"]
            out["coarse_opacity"] = coarse["opacity"]
        want_normals = self.cfg.shading.tilt and colour if normals is None else normals
        if want_normals:
            surf = o + out["depth"].detach()[:, None] * d
            out["normal"] = self.normals(surf)
        if colour:
            lit = None if light is None else (light, o)
            out["rgb"] = self.shade(out, out["albedo"], d, dnorm, frame, shading_mix, lit)
            if "coarse_rgb_albedo" in out:
                out["coarse_rgb"] = self.shade(
                    {**out, "depth": out["coarse_depth"]},
                    out.pop("coarse_rgb_albedo"),
                    d,
                    dnorm,
                    frame,
                    shading_mix,
                    lit,
                )
        return out

    def _composite(self, o, d, t, dnorm, far, colour: bool) -> dict[str, torch.Tensor]:
        b, s = t.shape
        x = self.to_grid((o[:, None, :] + t[..., None] * d[:, None, :]).reshape(-1, 3))
        deferred = self.field.deferred
        sparse = colour and deferred and hasattr(self.field, "features_at")
        prep = None
        if sparse:  # density first; albedo features only where the weight counts
            sigma, prep = self.field.density_prepared(x)
            feat = None
        elif colour:
            dirs = None
            if self.field.dir_dim and not deferred:
                dirs = d[:, None, :].expand(b, s, 3).reshape(-1, 3)
            sigma, feat = self.field(x, dirs)
        else:
            sigma, feat = self.field.density(x), None
        sigma = sigma.view(b, s)
        w, tau = composite(t, sigma, dnorm, far)
        opacity = w.sum(1)
        depth = (w * t).sum(1) / opacity.clamp_min(1e-6)
        # Transparent rays: fall back to the far bound instead of 0 (keeps r^2 finite).
        depth = torch.where(opacity > 1e-4, depth, far)
        out = {"t": t, "weights": w, "tau": tau, "opacity": opacity, "depth": depth}
        if sparse:
            keep = torch.nonzero(w.detach().reshape(-1) > WEIGHT_FLOOR)[:, 0]
            feat = self.field.features_at(x, prep, keep)
            out["albedo"] = self.albedo_of(feat, w.reshape(-1)[keep], keep // s, opacity, d)
            # what counted, for a pass that keeps the geometry fixed (colour_phase.py)
            out["points"], out["kept"] = x, keep
        elif colour:
            f = torch.bmm(w[:, None, :], feat.view(b, s, -1))[:, 0]
            if deferred:
                f = self.field.decode(f / opacity.clamp_min(1e-6)[:, None], d) * opacity[:, None]
            out["albedo"] = f
        return out

    def albedo_of(
        self,
        feat: torch.Tensor,
        w: torch.Tensor,
        ray: torch.Tensor,
        opacity: torch.Tensor,
        d: torch.Tensor,
    ) -> torch.Tensor:
        """A deferred field's albedo of B rays (B, 3) from the features of their samples that
        count (feat (K, C), their compositing weights w (K,) and rays `ray` (K,)): the features
        composited a ray, decoded once."""
        f = feat.new_zeros(len(opacity), feat.shape[1]).index_add(0, ray, w[:, None] * feat)
        return self.field.decode(f / opacity.clamp_min(1e-6)[:, None], d) * opacity[:, None]

    # --- photometry ---------------------------------------------------------------------------
    def gamma(self) -> torch.Tensor | float:
        return self.log_gamma.exp() if self.cfg.shading.learn_gamma else self.cfg.shading.gamma

    def radial_falloff(self, cos_axis: torch.Tensor) -> torch.Tensor:
        """F(theta) = exp(sum_k a_k (1 - cos theta)^k): the light's emission profile and the
        lens's vignetting in one (both depend on theta alone, see the module docstring)."""
        x = (1.0 - cos_axis.clamp(0.0, 1.0))[:, None]
        powers = x ** torch.arange(1, FALLOFF_TERMS + 1, device=x.device, dtype=x.dtype)
        return (powers * self.falloff).sum(-1).exp()

    def _exposure_centred(self) -> torch.Tensor:
        """Log exposures (frames x channels) minus their mean over the trained frames; a frame
        not trained on (held out) gets its trained neighbours' in time, interpolated by
        position: a scope's exposure changes smoothly, and the neighbours' images are what the
        neighbour average sees too (no look at the frame itself)."""
        w = self.exposure_trained > 0
        centred = self.exposure - self.exposure[w].mean(0) if w.any() else self.exposure * 0
        if w.all() or not w.any():
            return centred
        trained = torch.nonzero(w)[:, 0]
        pos = torch.arange(len(w), device=w.device)
        after = torch.searchsorted(trained, pos).clamp(max=len(trained) - 1)
        before = (after - 1).clamp(min=0)
        a, b = trained[before], trained[after]
        b = torch.where(b < pos, a, b)  # past the last trained frame: the last one
        a = torch.where(a > pos, b, a)  # before the first: the first one
        span = (b - a).clamp(min=1).to(centred.dtype)
        mix = ((pos - a).to(centred.dtype) / span).clamp(0, 1)[:, None]
        between = centred[a] * (1 - mix) + centred[b] * mix
        return torch.where(w[:, None], centred, between)

    def shade(self, out, albedo, d, dnorm, frame, mix: float, lit=None) -> torch.Tensor:
        """`lit`: (the light's pose in the scene frame, the rays' origins) for a light away from
        the rays' origins (see `render_rays`); None: the light at the camera centre."""
        cfg = self.cfg.shading
        if not cfg.enabled:
            lin = albedo
        else:
            if lit is None:  # the light at the camera centre: back along the ray
                r = (out["depth"] * dnorm).clamp_min(1e-3)
            else:
                to_light = lit[0][:3, 3] - (lit[1] + d * out["depth"][:, None])
                r = to_light.norm(dim=-1).clamp_min(1e-3)
                towards = to_light / r[:, None]
            if "normal" in out and cfg.tilt:
                if lit is None:  # -d / |d|, in the float order trained fields were fitted in
                    cos = (out["normal"] * d).sum(-1).neg().div(dnorm).clamp_min(0.0)
                else:
                    cos = (out["normal"] * towards).sum(-1).clamp_min(0.0)
                cos = mix * cos + (1.0 - mix)
            else:
                cos = torch.ones_like(r)
            ambient = nn.functional.softplus(self.ambient_raw)
            light = self.log_gain.exp() * cos / r.square() + ambient
            if cfg.falloff == "learned":
                # the surface's angle off the light's axis: the ray's own when the light is
                # at its camera (cos theta = 1 / |d|)
                axis = 1.0 / dnorm if lit is None else -(towards @ lit[0][:3, 2])
                light = light * self.radial_falloff(axis)
            lin = albedo * light[:, None]
            if cfg.exposure is True and frame is not None:
                lin = lin * self._exposure_centred()[frame].exp()
        return lin.clamp_min(1e-4) ** (1.0 / self.gamma())
