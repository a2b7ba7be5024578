"""Where to evaluate the field along rays: independent of the encoding (nerfacc's split).

Rays are x = o + t d with d's camera-frame z component equal to 1, so t *is* the z-depth.
The samplers take a density callback `density_fn(points (M, 3)) -> sigma (M,)` and return sorted
sample depths; `composite` turns densities at those depths into compositing weights.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F

DensityFn = Callable[[torch.Tensor], torch.Tensor]


def spaced(
    near: torch.Tensor,
    far: torch.Tensor,
    n: int,
    spacing: str = "log",
    jitter: bool = False,
    gen: torch.Generator | None = None,
) -> torch.Tensor:
    """(B,) bounds -> (B, n) stratified depths, one per bin; bin centres when not jittered."""
    b = near.shape[0]
    if jitter:
        u = torch.rand(b, n, generator=gen, device=near.device)
    else:
        u = torch.full((b, n), 0.5, device=near.device)
    u = (torch.arange(n, device=near.device) + u) / n
    near, far = near[:, None], far[:, None]
    if spacing == "log":
        return near * torch.exp(u * torch.log(far / near))
    return near + (far - near) * u


def composite(
    t: torch.Tensor, sigma: torch.Tensor, dnorm: torch.Tensor, far: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Volume rendering weights (B, S) and per-sample optical thickness sigma * delta (B, S).

    Sample i stands for [t_i, t_{i+1}); the last one for [t_S, far] (at least one spacing).
    """
    gaps = t[:, 1:] - t[:, :-1]
    last = (far - t[:, -1]).clamp_min(0)
    last = torch.maximum(last, gaps[:, -1] if gaps.shape[1] else last)
    delta = torch.cat([gaps, last[:, None]], 1) * dnorm[:, None]
    tau = sigma * delta
    alpha = 1.0 - torch.exp(-tau)
    trans = torch.exp(-torch.cumsum(torch.cat([tau.new_zeros(tau.shape[0], 1), tau[:, :-1]], 1), 1))
    return alpha * trans, tau


def weight_quantiles(
    t: torch.Tensor, weights: torch.Tensor, far: torch.Tensor, qs: tuple[float, ...]
) -> torch.Tensor:
    """(B, S) sorted samples and their compositing weights -> (B, len(qs)) depths below which
    the fractions `qs` of each ray's weight lie. Sample i's weight is spread evenly over its
    interval [t_i, t_i+1) (the last one up to `far`), as `composite` defines it, so the
    quantiles move smoothly with the field, not in steps of the sample spacing."""
    b, s = t.shape
    ends = torch.cat([t[:, 1:], torch.maximum(far, t[:, -1])[:, None]], 1)
    cdf = torch.cumsum(weights, 1)
    cdf = cdf / cdf[:, -1:].clamp_min(1e-12)
    q = torch.as_tensor(qs, dtype=t.dtype, device=t.device).expand(b, len(qs)).contiguous()
    idx = torch.searchsorted(cdf, q).clamp(max=s - 1)
    before = torch.where(idx > 0, cdf.gather(1, (idx - 1).clamp_min(0)), torch.zeros_like(q))
    mass = (cdf.gather(1, idx) - before).clamp_min(1e-12)
    frac = ((q - before) / mass).clamp(0, 1)
    t0 = t.gather(1, idx)
    return t0 + frac * (ends.gather(1, idx) - t0)


def sample_pdf(
    t: torch.Tensor,
    weights: torch.Tensor,
    n: int,
    jitter: bool = False,
    gen: torch.Generator | None = None,
) -> torch.Tensor:
    """Inverse-transform sampling of n depths from the piecewise-constant pdf of `weights`.

    Bins are centred on the samples t (edges at the midpoints, the outer edges at t_0, t_S-1).
    """
    b, s = t.shape
    edges = torch.cat([t[:, :1], 0.5 * (t[:, 1:] + t[:, :-1]), t[:, -1:]], 1)  # (B, S+1)
    w = weights + 1e-5
    pdf = w / w.sum(1, keepdim=True)
    cdf = torch.cat([pdf.new_zeros(b, 1), torch.cumsum(pdf, 1)], 1)
    cdf[:, -1] = 1.0
    if jitter:
        u = torch.rand(b, n, generator=gen, device=t.device)
        u = (torch.arange(n, device=t.device) + u) / n
    else:
        u = ((torch.arange(n, device=t.device) + 0.5) / n).expand(b, n)
    u = u.contiguous()
    idx = torch.searchsorted(cdf, u, right=True).clamp(1, s)
    c0, c1 = cdf.gather(1, idx - 1), cdf.gather(1, idx)
    e0, e1 = edges.gather(1, idx - 1), edges.gather(1, idx)
    frac = ((u - c0) / (c1 - c0).clamp_min(1e-12)).clamp(0, 1)
    return e0 + frac * (e1 - e0)


def _points(o: torch.Tensor, d: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    return (o[:, None, :] + t[..., None] * d[:, None, :]).reshape(-1, 3)


def two_pass(
    density_fn: DensityFn,
    o: torch.Tensor,
    d: torch.Tensor,
    near: torch.Tensor,
    far: torch.Tensor,
    n_coarse: int,
    n_fine: int,
    n_uniform: int,
    spacing: str = "log",
    jitter: bool = False,
    gen: torch.Generator | None = None,
) -> torch.Tensor:
    """Density-only pass without gradients over n_coarse spaced samples, then n_fine samples:
    n_fine - n_uniform drawn from the (dilated) weights, n_uniform stratified for exploration."""
    dnorm = d.norm(dim=-1)
    with torch.no_grad():
        t0 = spaced(near, far, n_coarse, spacing, jitter, gen)
        sigma = density_fn(_points(o, d, t0)).view(t0.shape)
        w, _ = composite(t0, sigma, dnorm, far)
        # Dilate: a sample next to a heavy one is worth refining too (surfaces between samples).
        w = F.max_pool1d(w[:, None], 3, 1, 1)[:, 0]
        n_imp = max(n_fine - n_uniform, 0)
        parts = []
        if n_imp:
            parts.append(sample_pdf(t0, w, n_imp, jitter, gen))
        if n_fine - n_imp:
            parts.append(spaced(near, far, n_fine - n_imp, spacing, jitter, gen))
        t, _ = torch.sort(torch.cat(parts, 1), 1)
    return t


def coarse_then_fine(
    t_coarse: torch.Tensor, w_coarse: torch.Tensor, n_fine: int, jitter: bool, gen=None
) -> torch.Tensor:
    """The paper's fine pass: n_fine importance samples merged with the coarse ones."""
    with torch.no_grad():
        tf = sample_pdf(t_coarse, w_coarse.detach(), n_fine, jitter, gen)
        t, _ = torch.sort(torch.cat([t_coarse, tf], 1), 1)
    return t
