"""A lumen that breathes under a moving camera: one canonical lumen, its wall scaled about the
centre curve by a few numbers per time.

A point x seen at time t is read from the field at foot + (x - foot) e^(-g(s, t)), with foot
its closest point on the centre curve, s that point's place along the curve and g a table over
(place, time) interpolated bilinearly, whose mean over time is zero at every place (so the
canonical lumen is the time-mean one and the gauge is fixed without a penalty).

Why this form: a free change over time (the dynamic field's space-time planes) under a moving
camera absorbs what parallax would pin (docs/experiments.md); a scale about the centre curve
is what a breathing lumen does, and a table of knots x times numbers cannot fake a wrong depth
across a frame. The curve is the centerline stage's, in scene units, kept in the state dict so
a saved model rebuilds it.
"""

from __future__ import annotations

import torch
from torch import nn

from endopipe.stages.centerline.prior.tube import TubePrior


class LumenBreathing(nn.Module):
    """g(s, t) on `knots` places along `curve` (M, 3) and `times` nodes over t in [-1, 1]."""

    def __init__(self, curve: torch.Tensor, knots: int, times: int) -> None:
        super().__init__()
        self.register_buffer("curve", torch.as_tensor(curve, dtype=torch.float32).clone())
        self.table = nn.Parameter(torch.zeros(max(int(knots), 1), max(int(times), 1)))
        self._tube: TubePrior | None = None

    @property
    def tube(self) -> TubePrior:
        """The curve as a tube (radius unused), with its nearest-segment grid, built once."""
        if self._tube is None:
            self._tube = TubePrior(self.curve.detach().cpu().double().numpy(), 1.0)
        return self._tube

    def centred(self) -> torch.Tensor:
        """The table less its mean over time at each place: (knots, times)."""
        return self.table - self.table.mean(1, keepdim=True)

    def log_scale(self, s: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """g at arc lengths `s` (clamped to the curve) and times `t` in [-1, 1], bilinear."""
        g = self.centred()
        k, n = g.shape
        u = (s / max(self.tube.length, 1e-12)).clamp(0.0, 1.0) * (k - 1)
        v = ((t + 1.0) * 0.5).clamp(0.0, 1.0) * (n - 1)
        iu = u.floor().clamp(max=max(k - 2, 0)).long()
        iv = v.floor().clamp(max=max(n - 2, 0)).long()
        fu, fv = u - iu, v - iv
        ju, jv = (iu + 1).clamp(max=k - 1), (iv + 1).clamp(max=n - 1)
        top = g[iu, iv] * (1 - fv) + g[iu, jv] * fv
        bottom = g[ju, iv] * (1 - fv) + g[ju, jv] * fv
        return top * (1 - fu) + bottom * fu

    def canonical(self, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """The canonical points (N, 3) of scene points `x` (N, 3) seen at times `t` (N,)."""
        near = self.tube.closest(x.detach(), refine=False)
        foot = near["foot"].to(x.dtype)
        shrink = torch.exp(-self.log_scale(near["s"].to(x.dtype), t.to(x.dtype)))
        return foot + (x - foot) * shrink[:, None]

    def smoothness(self) -> torch.Tensor:
        """Mean square of the table's steps between time nodes (breathing is slow)."""
        if self.table.shape[1] < 2:
            return self.table.new_zeros(())
        return self.table.diff(dim=1).square().mean()

    def amplitude(self) -> float:
        """The largest relative radius change from the mean, for the log and summary."""
        with torch.no_grad():
            return float(torch.expm1(self.centred().abs().max()))
