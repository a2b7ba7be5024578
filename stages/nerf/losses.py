"""The loss terms of seed §3.3-3.5, as plain functions of rendered quantities.

L = L_photo + l1 L_prior + l2 L_smooth + l3 L_geo, with l1 decaying from a multiple of itself
(coarse to fine: the prior first fixes the global geometry, then lets details through).
"""

from __future__ import annotations

import torch


def photo(
    rgb: torch.Tensor,
    target: torch.Tensor,
    valid: torch.Tensor,
    saturation: float = 2.0,
    trim: float = 0.0,
) -> torch.Tensor:
    """Masked L2 (mean over usable rays and channels); specular pixels are masked by ingest.

    A channel at or above `saturation` was clipped by the camera: it only says "at least this
    bright", so a rendering brighter than it is not penalised (near walls under the endoscope's
    light clip often; treating them as exact pushes the wall away to dim it). `trim` > 0 leaves
    out that fraction of the batch's largest residuals."""
    diff = rgb - target
    diff = torch.where(target >= saturation, diff.clamp(max=0.0), diff)
    err = diff.square().mean(-1)
    v = valid.to(err.dtype)
    if trim > 0 and err.numel() > 1:
        # Drop the largest residuals of the batch (highlights the mask missed, occlusions).
        cut = torch.quantile(err.detach()[valid], 1.0 - trim) if valid.any() else err.max()
        v = v * (err.detach() <= cut).to(err.dtype)
    return (err * v).sum() / v.sum().clamp_min(1.0)


def psnr(mse: torch.Tensor | float) -> float:
    m = float(mse)
    return float("inf") if m <= 0 else -10.0 * torch.log10(torch.tensor(m)).item()


def core_density(tau: torch.Tensor, in_core: torch.Tensor) -> torch.Tensor:
    """Optical thickness accumulated inside the lumen's core, per ray, averaged (seed §3.3)."""
    return (tau * in_core.to(tau.dtype)).sum(1).mean()


def wall_attraction(
    depth: torch.Tensor,
    opacity: torch.Tensor,
    wall: torch.Tensor,
    has_wall: torch.Tensor,
    tolerance: float,
) -> torch.Tensor:
    """Surface near the prior's wall: relative depth error beyond `tolerance` (a hinge, so a
    rough prior does not bias the fine shape), plus full opacity for rays that meet the wall."""
    rel = ((depth - wall).abs() / wall.clamp_min(1e-6) - tolerance).clamp_min(0.0)
    term = rel + (1.0 - opacity).clamp_min(0.0)
    v = has_wall.to(term.dtype)
    return (term * v).sum() / v.sum().clamp_min(1.0)


def normal_variance(normals: torch.Tensor) -> torch.Tensor:
    """(P, n, 3) normals of P patches: mean squared deviation from each patch's mean normal."""
    mean = normals.mean(1, keepdim=True)
    return (normals - mean).square().sum(-1).mean()


def edge_aware_smoothness(depth: torch.Tensor, image: torch.Tensor, order: int, edge_scale: float):
    """(P, p, p) depth patches, (P, p, p, 3) image patches: depth gradients (normalised by the
    patch's mean depth) weighted by exp(-edge_scale |grad I|) (seed §3.4)."""
    z = depth / depth.mean((1, 2), keepdim=True).detach().clamp_min(1e-6)
    gx_i = (image[:, :, 1:] - image[:, :, :-1]).abs().mean(-1)
    gy_i = (image[:, 1:] - image[:, :-1]).abs().mean(-1)
    if order == 1:
        gx = (z[:, :, 1:] - z[:, :, :-1]).abs()
        gy = (z[:, 1:] - z[:, :-1]).abs()
        wx, wy = torch.exp(-edge_scale * gx_i), torch.exp(-edge_scale * gy_i)
    else:
        gx = (z[:, :, 2:] - 2 * z[:, :, 1:-1] + z[:, :, :-2]).abs()
        gy = (z[:, 2:] - 2 * z[:, 1:-1] + z[:, :-2]).abs()
        wx = torch.exp(-edge_scale * torch.maximum(gx_i[:, :, 1:], gx_i[:, :, :-1]))
        wy = torch.exp(-edge_scale * torch.maximum(gy_i[:, 1:], gy_i[:, :-1]))
    return (gx * wx).mean() + (gy * wy).mean()


def geometric_consistency(
    z_warped: torch.Tensor, z_rendered: torch.Tensor, valid: torch.Tensor
) -> torch.Tensor:
    """Relative difference of frame t's depth warped into t+1 and t+1's rendered depth there."""
    rel = (z_warped - z_rendered).abs() / z_warped.detach().clamp_min(1e-6)
    v = valid.to(rel.dtype)
    return (rel * v).sum() / v.sum().clamp_min(1.0)


def sparse_depth(
    depth: torch.Tensor, target: torch.Tensor, delta: float = 0.05, cap: float = 0.5
) -> torch.Tensor:
    """Huber on the relative depth error at SfM points (quadratic under `delta`); a point off
    by more than `cap` is left out (a track across a fold's silhouette, a bad triangulation)."""
    rel = (depth - target) / target.clamp_min(1e-6)
    a = rel.abs()
    huber = torch.where(a < delta, 0.5 * a.square() / delta, a - 0.5 * delta)
    keep = (a.detach() < cap).to(huber.dtype)
    return (huber * keep).sum() / keep.sum().clamp_min(1.0)


def depth_spread(t: torch.Tensor, weights: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Each ray's render weights (B, S) at depths t times their squared relative distance from
    its measured depth, averaged over the rays: zero only when the ray's weight sits at it."""
    rel = (t - target[:, None]) / target[:, None].clamp_min(1e-6)
    return (weights * rel.square().clamp_max(1.0)).sum(1).mean()


def distortion(t: torch.Tensor, weights: torch.Tensor, far: torch.Tensor) -> torch.Tensor:
    """Mip-NeRF 360's distortion loss on (B, S) sorted samples: small when each ray's weight
    sits in one compact interval. Without it the field fills the space in front of the wall
    with a semi-transparent ramp (measured: 10-90% weight spread ~2 mm on a 14 mm colon, and
    expected depth ~5% short), which blurs depth maps and meshes."""
    ends = torch.cat([t[:, 1:], torch.maximum(far, t[:, -1])[:, None]], 1)
    gaps = (ends - t).clamp_min(0)
    # The last interval can reach the far bound: cap it at the median spacing of the ray.
    gaps = torch.minimum(gaps, gaps.median(1, keepdim=True).values * 4 + 1e-6)
    mid = t + 0.5 * gaps
    w = weights
    w_before = torch.cumsum(w, 1) - w
    wm_before = torch.cumsum(w * mid, 1) - w * mid
    cross = 2.0 * (w * (mid * w_before - wm_before)).sum(1)
    own = (w.square() * gaps).sum(1) / 3.0
    return (cross + own).mean()


def prior_multiplier(progress: float, start: float, decay: float) -> float:
    """Coarse to fine: lambda_1 x start at the beginning, decaying geometrically to x1 when the
    training progress reaches `decay`."""
    return float(start ** max(0.0, 1.0 - progress / decay))


def prior_depth(
    depth: torch.Tensor, prior: torch.Tensor, delta: float = 0.05, eps: float = 1e-8
) -> torch.Tensor:
    """Scale-and-shift-invariant depth loss on (F, R) rays, R per frame (MiDaS-style): each
    frame's prior mapped onto our depth by its least-squares scale (at least 0) and shift, then
    a Huber on the residual relative to the frame's median depth. Invariant to any positive
    scale and any shift of the prior, and to a scale of our depth: a relative prior shapes the
    depth of each frame, never its scale."""
    p_mean = prior.mean(1, keepdim=True)
    d_mean = depth.mean(1, keepdim=True)
    pc, dc = prior - p_mean, depth - d_mean
    scale = (pc * dc).sum(1, keepdim=True) / pc.square().sum(1, keepdim=True).clamp_min(eps)
    scale = scale.clamp_min(0.0)
    fitted = scale * pc + d_mean
    unit = depth.detach().median(1, keepdim=True).values.abs().clamp_min(eps)
    a = ((depth - fitted) / unit).abs()
    huber = torch.where(a < delta, 0.5 * a.square() / delta, a - 0.5 * delta)
    return huber.mean()
