"""Tensor helpers every prior shape shares: one conversion of whatever the caller passes, and
the ray bookkeeping that turns unit-direction distances into the caller's units."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

Tensorish = Any  # torch.Tensor | np.ndarray | sequence


def as_tensor(x: Tensorish) -> torch.Tensor:
    t = x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))
    if not t.is_floating_point():
        t = t.to(torch.float32)
    return t


def flat_rays(
    origins: Tensorish, dirs: Tensorish
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rays as flat (N, 3) origins and unit directions, and the directions' norms (N,)."""
    o = as_tensor(origins)
    d = as_tensor(dirs).to(device=o.device, dtype=o.dtype)
    o, d = torch.broadcast_tensors(o, d)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    dnorm = d.norm(dim=-1).clamp_min(1e-12)
    return o, d / dnorm[:, None], dnorm


def near_far(
    near_fraction: float, radius_o: torch.Tensor, far: torch.Tensor, dnorm: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    far = far.clamp_min(1e-6)
    near = torch.minimum(near_fraction * radius_o, 0.5 * far)
    return near / dnorm, far / dnorm


def dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Row-wise dot product of (N, 3) tensors (a matrix-vector product: much faster on CPU
    than a reduction over a last axis of 3)."""
    return (a * b) @ a.new_ones(3)
