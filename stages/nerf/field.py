"""Radiance fields: density sigma(x) and a view-independent albedo a(x) over grid coordinates.

Every field offers the same small interface, which is all the sampler and the renderer use:
`density(x)` (no colour work: the sampler's first pass), `forward(x, d)` -> (sigma, albedo),
`param_groups(lr_grid, lr_mlp)` and `on_progress(p)` (True when the parameters were replaced,
e.g. a TensoRF upsampling, so the optimiser must be rebuilt).

A field with `deferred = True` returns per-sample *features* instead of albedo; the renderer
composites them along the ray (normalised by opacity) and calls `decode(features, d)` once per
ray. TensoRF does this by default: its albedo MLP then costs one evaluation per ray instead of
one per sample, the largest saving on a CPU (the albedo of a surface point is unchanged: a(x) =
decode(features(x))).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from endopipe.pipeline.errors import ConfigError
from endopipe.stages.nerf.encodings import (
    HashGrid,
    VMGrid,
    VMTimeGrid,
    sinusoidal,
    sinusoidal_dim,
)
from endopipe.stages.nerf.field_config import FieldConfig


def _mlp(dims: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(dims) - 1):
        layers.append(nn.Linear(dims[i], dims[i + 1]))
        if i < len(dims) - 2:
            layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


def _inside(x: torch.Tensor) -> torch.Tensor:
    return (x[..., :3].abs() <= 1.0).all(-1)


class RadianceField(nn.Module):
    """Base: subclasses implement `density` and `forward` (and `decode` when deferred)."""

    deferred: bool = False

    def __init__(self, cfg: FieldConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.dir_dim = sinusoidal_dim(3, cfg.dir_bands) if cfg.view_dependent else 0
        # Signed-distance geometry: the Laplace CDF's width now (a buffer: a loaded model renders
        # with its last width), and the starting distance on a coarse grid (1, 1, D, H, W) over
        # [-1, 1]^3, set by the trainer from the prior (sdf_start.py; empty until then).
        self.register_buffer("beta", torch.tensor(cfg.sdf.beta_init), persistent=True)
        self.register_buffer("start", torch.zeros(0), persistent=True)

    @property
    def is_sdf(self) -> bool:
        return self.cfg.geometry == "sdf"

    @property
    def dynamic(self) -> bool:
        """Whether the geometry changes with time (see `VMTimeGrid`)."""
        return self.cfg.dynamic is True

    @property
    def timed(self) -> bool:
        """Whether points carry a fourth coordinate, the time: a dynamic field's, or a rigid
        one whose albedo changes with time (`appearance_time`)."""
        return self.dynamic or self.cfg.appearance_time is True

    @property
    def cell(self) -> float:
        """Typical grid cell in grid coordinates (finite-difference step of normals)."""
        return 2.0 / 256

    def _activate(self, raw: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        if self.is_sdf:
            sigma = laplace_density(self._signed(raw, x), self.beta)
        else:
            sigma = F.softplus(raw + self.cfg.density_bias) * self.cfg.density_scale
        return sigma * _inside(x).to(sigma.dtype)

    def _signed(self, raw: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """The signed distance (scene units): a learned residual over the starting distance
        (the prior's wall, or spheres about the cameras). The residual is scaled down so that
        an optimiser step moves the surface by a small part of a radius."""
        return self._start_at(x) + self.cfg.sdf.residual_scale * raw

    def _start_at(self, x: torch.Tensor) -> torch.Tensor:
        if self.start.numel() == 0:  # not placed by a trainer yet
            return torch.zeros_like(x[:, 0])
        g = x[:, :3].reshape(1, -1, 1, 1, 3).to(self.start.dtype)
        v = F.grid_sample(self.start, g, mode="bilinear", padding_mode="border", align_corners=True)
        return v.view(-1).to(x.dtype)

    def signed_distance(self, x: torch.Tensor) -> torch.Tensor:
        """d at grid points (signed-distance geometry only)."""
        return self._signed(self._raw(x), x)

    def _raw(self, x: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def set_beta(self, progress: float) -> None:
        """Geometric schedule from beta_init to beta_final: a wide ramp lets the first steps
        find the wall, a thin one puts the weight on one surface at the end."""
        c = self.cfg.sdf
        p = min(max(progress, 0.0), 1.0)
        self.beta.fill_(c.beta_init * (c.beta_final / c.beta_init) ** p)

    def _dir_features(self, d: torch.Tensor | None, n: int, like: torch.Tensor) -> list:
        if not self.dir_dim:
            return []
        if d is None:
            return [like.new_zeros(n, self.dir_dim)]
        d = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-9)
        return [sinusoidal(d, self.cfg.dir_bands)]

    def density(self, x: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def forward(
        self, x: torch.Tensor, d: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        raise NotImplementedError

    def decode(self, features: torch.Tensor, d: torch.Tensor | None = None) -> torch.Tensor:
        """Composited features (B, C) -> albedo (B, 3); identity for non-deferred fields."""
        return features

    def param_groups(self, lr_grid: float, lr_mlp: float) -> list[dict]:
        return [{"params": list(self.parameters()), "lr": lr_mlp, "name": "mlp"}]

    def on_progress(self, progress: float) -> bool:
        """Called before every step with the training progress in [0, 1]; True when the
        parameters were replaced (the optimiser must then be rebuilt)."""
        if self.is_sdf:
            self.set_beta(progress)
        return False

    def extra_loss(self) -> torch.Tensor | None:
        return None


class TensorfField(RadianceField):
    """TensoRF VM grids for density and albedo features, then a small colour MLP."""

    def __init__(self, cfg: FieldConfig, box_extent: tuple[float, float, float]) -> None:
        super().__init__(cfg)
        t = cfg.tensorf
        self.extent = tuple(float(e) for e in box_extent)
        res = self._res(t.res_init)
        if cfg.dynamic is True:
            self.density_grid = VMTimeGrid(res, t.density_components, cfg.time_nodes, 0.1)
        else:
            self.density_grid = VMGrid(res, t.density_components, init_std=0.1)
        albedo = t.albedo_components(cfg.dynamic is True)
        if self.timed:
            self.app_grid = VMTimeGrid(res, albedo, cfg.time_nodes, 0.1)
        else:
            self.app_grid = VMGrid(res, albedo, init_std=0.1)
        self.basis = nn.Linear(3 * albedo, t.appearance_dim, bias=False)
        h = cfg.color_hidden
        self.color = _mlp([t.appearance_dim + self.dir_dim, h, h, 3])
        self.register_buffer("res_now", torch.tensor(res), persistent=True)
        self.deferred = t.composite_features

    def _res(self, longest: int) -> tuple[int, int, int]:
        cell = max(self.extent) / (longest - 1)
        return tuple(int(max(8, round(e / cell) + 1)) for e in self.extent)  # type: ignore

    def schedule(self) -> list[tuple[float, tuple[int, int, int]]]:
        """(progress, resolution) of every upsampling: log-spaced sizes up to res_final."""
        t = self.cfg.tensorf
        k = len(t.upsample_at)
        if k == 0 or t.res_final == t.res_init:
            return []
        sizes = torch.linspace(math.log(t.res_init), math.log(t.res_final), k + 1).exp()
        return [
            (float(f), self._res(int(round(float(s)))))
            for f, s in zip(t.upsample_at, sizes[1:], strict=True)
        ]

    @property
    def cell(self) -> float:
        return 2.0 / (max(self.density_grid.res) - 1)

    def _where(self, x: torch.Tensor) -> torch.Tensor:
        """The points as the density grid reads them: a rigid geometry ignores their time."""
        return x if self.dynamic else x[:, :3]

    @property
    def _shared(self) -> bool:
        """Whether both grids read a point alike (one interpolation set-up for both)."""
        return self.dynamic or not self.timed

    def _raw(self, x: torch.Tensor) -> torch.Tensor:
        return self.density_grid(self._where(x)).sum(-1)

    def density(self, x: torch.Tensor) -> torch.Tensor:
        return self._activate(self._raw(x), x)

    def forward(self, x: torch.Tensor, d: torch.Tensor | None = None):
        sigma, prep = self.density_prepared(x)
        f = self.app_grid(x, prep if self._shared else None)  # prep None: its own read
        if self.deferred:
            return sigma, f
        return sigma, self.decode(f, d)

    def density_prepared(self, x: torch.Tensor) -> tuple[torch.Tensor, tuple | None]:
        """sigma at grid points and the interpolation set-up, for `features_at` later (None:
        a read that wants no gradient needs none)."""
        at = self._where(x)
        if self.density_grid.reads_fused(at):  # no gradient wanted: no set-up to share
            return self._activate(self.density_grid(at).sum(-1), x), None
        prep = self.density_grid.prepare(at)  # both grids share their resolution
        return self._activate(self.density_grid(at, prep).sum(-1), x), prep

    def features_at(self, x: torch.Tensor, prep: tuple | None, keep: torch.Tensor) -> torch.Tensor:
        """The albedo features of the points `keep` (indices) of a prepared set (a deferred
        field's: composited, then decoded once a ray)."""
        if prep is None or not self._shared:  # its own read (with the time, or no set-up)
            return self.app_grid(x[keep])
        return self.app_grid(x[keep], self.app_grid.select(prep, keep, x.shape[0]))

    def decode(self, features: torch.Tensor, d: torch.Tensor | None = None) -> torch.Tensor:
        h = torch.cat(
            [self.basis(features), *self._dir_features(d, features.shape[0], features)], -1
        )
        return torch.sigmoid(self.color(h))

    def param_groups(self, lr_grid: float, lr_mlp: float) -> list[dict]:
        grids = [*self.density_grid.parameters(), *self.app_grid.parameters()]
        mlp = [*self.basis.parameters(), *self.color.parameters()]
        return [
            {"params": grids, "lr": lr_grid, "name": "grid"},
            {"params": mlp, "lr": lr_mlp, "name": "mlp"},
        ]

    def set_resolution(self, res: tuple[int, int, int]) -> None:
        self.density_grid = self.density_grid.upsampled(res)
        self.app_grid = self.app_grid.upsampled(res)
        self.res_now = torch.tensor(res)

    def slice_times_up_to(self, n: int) -> None:
        """Points at up to n distinct times read their lines sliced at those times (a batch
        drawn from n frames, `RaySampler`); kept across upsamplings."""
        for grid in (self.density_grid, self.app_grid):
            if isinstance(grid, VMTimeGrid):
                grid.slice_up_to = max(int(n), 1)

    def on_progress(self, progress: float) -> bool:
        super().on_progress(progress)
        res = self._res(self.cfg.tensorf.res_init)
        for at, r in self.schedule():
            if progress >= at:
                res = r
        if tuple(self.density_grid.res) != res:
            self.set_resolution(res)
            return True
        return False

    def extra_loss(self) -> torch.Tensor | None:
        w = self.cfg.tensorf.tv_weight
        loss = w * self.density_grid.total_variation() if w > 0 else None
        if self.timed and self.cfg.change_weight > 0:
            change = self.app_grid.change_penalty()
            if self.dynamic:
                change = change + self.density_grid.change_penalty()
            change = self.cfg.change_weight * change
            loss = change if loss is None else loss + change
        return loss

    def albedo_loss(self) -> torch.Tensor | None:
        """The part of `extra_loss` that moves the albedo grid (its change over time)."""
        if self.timed and self.cfg.change_weight > 0:
            return self.cfg.change_weight * self.app_grid.change_penalty()
        return None


class HashgridField(RadianceField):
    """Multiresolution hash encoding, a density MLP and an albedo MLP (Instant-NGP layout)."""

    def __init__(self, cfg: FieldConfig) -> None:
        super().__init__(cfg)
        h = cfg.hashgrid
        self.encoding = HashGrid(h.levels, h.features, h.log2_size, h.base_res, h.max_res)
        self.sigma_net = _mlp([self.encoding.out_dim, h.hidden, 1 + h.geo_features])
        self.color = _mlp([h.geo_features + self.dir_dim, cfg.color_hidden, cfg.color_hidden, 3])

    @property
    def cell(self) -> float:
        return 2.0 / self.cfg.hashgrid.max_res

    def _geo(self, x: torch.Tensor) -> torch.Tensor:
        return self.sigma_net(self.encoding(x))

    def _raw(self, x: torch.Tensor) -> torch.Tensor:
        return self._geo(x)[:, 0]

    def density(self, x: torch.Tensor) -> torch.Tensor:
        return self._activate(self._raw(x), x)

    def forward(self, x: torch.Tensor, d: torch.Tensor | None = None):
        g = self._geo(x)
        sigma = self._activate(g[:, 0], x)
        h = torch.cat([g[:, 1:], *self._dir_features(d, x.shape[0], g)], -1)
        return sigma, torch.sigmoid(self.color(h))

    def param_groups(self, lr_grid: float, lr_mlp: float) -> list[dict]:
        mlp = [*self.sigma_net.parameters(), *self.color.parameters()]
        return [
            {"params": list(self.encoding.parameters()), "lr": lr_grid, "name": "grid"},
            {"params": mlp, "lr": lr_mlp, "name": "mlp"},
        ]


class PositionalField(RadianceField):
    """The paper's MLP: 8 x 256 ReLU layers over a 10-band encoding, a skip at layer 4."""

    def __init__(self, cfg: FieldConfig) -> None:
        super().__init__(cfg)
        p = cfg.positional
        self.in_dim = sinusoidal_dim(3, p.pos_bands)
        layers = []
        for i in range(p.depth):
            din = self.in_dim if i == 0 else p.width
            if p.skip and i == p.skip:
                din += self.in_dim
            layers.append(nn.Linear(din, p.width))
        self.layers = nn.ModuleList(layers)
        self.sigma_head = nn.Linear(p.width, 1)
        self.feature = nn.Linear(p.width, p.width)
        self.color = _mlp([p.width + self.dir_dim, p.width // 2, 3])

    @property
    def cell(self) -> float:
        return 2.0 / (2**self.cfg.positional.pos_bands)

    def _trunk(self, x: torch.Tensor) -> torch.Tensor:
        e = sinusoidal(x, self.cfg.positional.pos_bands)
        h = e
        for i, layer in enumerate(self.layers):
            if self.cfg.positional.skip and i == self.cfg.positional.skip:
                h = torch.cat([h, e], -1)
            h = F.relu(layer(h))
        return h

    def _raw(self, x: torch.Tensor) -> torch.Tensor:
        return self.sigma_head(self._trunk(x))[:, 0]

    def density(self, x: torch.Tensor) -> torch.Tensor:
        return self._activate(self._raw(x), x)

    def forward(self, x: torch.Tensor, d: torch.Tensor | None = None):
        h = self._trunk(x)
        sigma = self._activate(self.sigma_head(h)[:, 0], x)
        f = torch.cat([self.feature(h), *self._dir_features(d, x.shape[0], h)], -1)
        return sigma, torch.sigmoid(self.color(f))


def laplace_density(d: torch.Tensor, beta: torch.Tensor) -> torch.Tensor:
    """VolSDF: sigma = Psi_beta(-d) / beta, Psi the Laplace CDF of scale beta. Half the peak
    on the zero level, falling as exp(-d / beta) into free space."""
    e = torch.exp(-d.abs() / beta)
    psi = torch.where(d >= 0, 0.5 * e, 1.0 - 0.5 * e)
    return psi / beta


def make_field(cfg: FieldConfig, box_extent: tuple[float, float, float]) -> RadianceField:
    if cfg.dynamic is True and (cfg.encoding != "tensorf" or cfg.geometry == "sdf"):
        raise ConfigError(
            "nerf.field.dynamic=true needs the tensorf encoding and density geometry; set "
            "nerf.field.encoding=tensorf and nerf.field.geometry=density"
        )
    if cfg.appearance_time is True and cfg.encoding != "tensorf":
        raise ConfigError(
            "nerf.field.appearance_time=true needs the tensorf encoding; set "
            "nerf.field.encoding=tensorf or nerf.field.appearance_time=auto"
        )
    if cfg.encoding == "tensorf":
        return TensorfField(cfg, box_extent)
    if cfg.encoding == "hashgrid":
        return HashgridField(cfg)
    return PositionalField(cfg)
