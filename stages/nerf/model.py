"""The NeRF model: a field in a scene box, the sampler, compositing and the near-light shading.

Rays live in the scene frame (see scene.py) with directions whose camera-frame z is 1, so every
depth `t` here is a z-depth in scene units (world z-depth = t * box.scale).

Shading (seed §3.2) is deferred to the ray's expected surface point: the composited albedo is lit
by gain * max(n.l, 0) / r^2 + ambient, with the light at the camera centre (l = -ray direction),
r the distance to the expected surface and n the normalised negative density gradient there
(central finite differences of `field.density`, so any encoding works and no double backward is
needed). A per-frame exposure is optional. Frames are display-encoded: colour^(1/gamma).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from endopipe.stages.nerf.config import NerfConfig
from endopipe.stages.nerf.field import RadianceField, make_field
from endopipe.stages.nerf.sampling import coarse_then_fine, composite, spaced, two_pass
from endopipe.stages.nerf.scene import SceneBox


class NerfModel(nn.Module):
    def __init__(self, cfg: NerfConfig, box: SceneBox, n_frames: int, gain: float = 1.0) -> None:
        super().__init__()
        self.cfg = cfg
        self.box = box
        self.field: RadianceField = make_field(cfg.field, tuple(box.extent))
        self.log_gain = nn.Parameter(torch.tensor(math.log(gain)), requires_grad=True)
        amb = max(cfg.shading.ambient, 1e-6)
        self.ambient_raw = nn.Parameter(torch.tensor(math.log(math.expm1(amb))))
        self.exposure = nn.Parameter(torch.zeros(max(n_frames, 1)))

    def load_state_dict(self, state, strict: bool = True, assign: bool = False):  # type: ignore
        """Also restores a TensoRF grid's resolution (it changes while training)."""
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
        shade = [self.ambient_raw]
        if self.cfg.shading.learn_gain:
            shade.append(self.log_gain)
        if self.cfg.shading.exposure:
            shade.append(self.exposure)
        groups.append({"params": shade, "lr": lr_mlp, "name": "shading"})
        return groups

    # --- geometry helpers ---------------------------------------------------------------------
    def to_grid(self, x: torch.Tensor) -> torch.Tensor:
        return self.box.to_grid(x)

    def density_scene(self, x: torch.Tensor) -> torch.Tensor:
        """sigma at scene points (M, 3)."""
        return self.field.density(self.to_grid(x))

    def normals(self, x: torch.Tensor) -> torch.Tensor:
        """Unit normals -grad sigma / |grad sigma| at scene points (B, 3), central differences
        with a step of `normal_eps` grid cells (cells of the unwarped core)."""
        x = x.detach()
        h = self.cfg.shading.normal_eps * self.field.cell * 0.5 * float(self.box.extent.max())
        eye = torch.eye(3, device=x.device, dtype=x.dtype) * h
        pts = torch.cat([x[:, None, :] + eye, x[:, None, :] - eye], 1).reshape(-1, 3)
        s = self.density_scene(pts).view(-1, 2, 3)
        grad = s[:, 0] - s[:, 1]
        return -grad / grad.norm(dim=-1, keepdim=True).clamp_min(1e-6)

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
                self.density_scene,
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
    ) -> dict[str, torch.Tensor]:
        """Render rays (scene frame). Returns depth (z, scene units), opacity, and when `colour`:
        rgb (display-encoded), plus normal/cos when computed, the samples t and weights."""
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
        want_normals = self.cfg.shading.enabled and colour if normals is None else normals
        if want_normals:
            surf = o + out["depth"].detach()[:, None] * d
            out["normal"] = self.normals(surf)
        if colour:
            out["rgb"] = self.shade(out, out["albedo"], d, dnorm, frame, shading_mix)
            if "coarse_rgb_albedo" in out:
                out["coarse_rgb"] = self.shade(
                    {**out, "depth": out["coarse_depth"]},
                    out.pop("coarse_rgb_albedo"),
                    d,
                    dnorm,
                    frame,
                    shading_mix,
                )
        return out

    def _composite(self, o, d, t, dnorm, far, colour: bool) -> dict[str, torch.Tensor]:
        b, s = t.shape
        x = self.to_grid((o[:, None, :] + t[..., None] * d[:, None, :]).reshape(-1, 3))
        deferred = self.field.deferred
        if colour:
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
        if colour:
            f = torch.bmm(w[:, None, :], feat.view(b, s, -1))[:, 0]
            if deferred:
                f = self.field.decode(f / opacity.clamp_min(1e-6)[:, None], d) * opacity[:, None]
            out["albedo"] = f
        return out

    def shade(self, out, albedo, d, dnorm, frame, mix: float) -> torch.Tensor:
        cfg = self.cfg.shading
        if not cfg.enabled:
            lin = albedo
        else:
            r = (out["depth"] * dnorm).clamp_min(1e-3)
            if "normal" in out:
                cos = (out["normal"] * d).sum(-1).neg().div(dnorm).clamp_min(0.0)
                cos = mix * cos + (1.0 - mix)
            else:
                cos = torch.ones_like(r)
            ambient = nn.functional.softplus(self.ambient_raw)
            light = self.log_gain.exp() * cos / r.square() + ambient
            lin = albedo * light[:, None]
            if cfg.exposure and frame is not None:
                lin = lin * self.exposure[frame].exp()[:, None]
        return lin.clamp_min(1e-4) ** (1.0 / self.cfg.shading.gamma)
