"""The cavity prior: an ellipsoid (centre, semi-axes, rotation) for a chamber such as the
stomach or bladder; exact point-to-ellipsoid distance by bisection on the Lagrange multiplier,
analytic ray intersection."""

from __future__ import annotations

import numpy as np
import torch

from endopipe.stages.centerline.prior.base import LumenPrior
from endopipe.stages.centerline.prior.tensors import Tensorish, as_tensor, flat_rays, near_far


class EllipsoidPrior(LumenPrior):
    """A cavity: the ellipsoid {c + R y : sum (y_i / a_i)^2 <= 1}, R's columns its axes."""

    kind = "cavity"

    def __init__(
        self,
        centre: Tensorish,
        axes: Tensorish,
        rotation: Tensorish | None = None,
        *,
        far_radii: float = 6.0,
    ) -> None:
        def arr(a: Tensorish) -> np.ndarray:
            a = a.detach().cpu().numpy() if isinstance(a, torch.Tensor) else a
            return np.asarray(a, np.float64)

        c = arr(centre).reshape(3)
        ax = arr(axes).reshape(3)
        rot = np.eye(3) if rotation is None else arr(rotation).reshape(3, 3)
        if np.any(ax <= 0):
            raise ValueError("ellipsoid semi-axes must be positive")
        # Sort axes longest first (the bisection below assumes the last one is the shortest)
        # and make the frame right-handed.
        order = np.argsort(-ax)
        ax, rot = ax[order], rot[:, order]
        if np.linalg.det(rot) < 0:
            rot[:, 2] = -rot[:, 2]
        self.centre, self.axes, self.rotation = c, ax, rot
        self.far_radii = float(far_radii)
        self._cache: dict[tuple[str, torch.dtype], dict[str, torch.Tensor]] = {}

    @property
    def own_radius(self) -> float:
        return float(np.prod(self.axes) ** (1.0 / 3.0))

    def _buffers(self, device: torch.device, dtype: torch.dtype) -> dict[str, torch.Tensor]:
        key = (str(device), dtype)
        if key not in self._cache:
            self._cache[key] = {
                k: torch.as_tensor(v).to(device=device, dtype=dtype)
                for k, v in (("c", self.centre), ("a", self.axes), ("R", self.rotation))
            }
        return self._cache[key]

    def local(self, x: Tensorish) -> torch.Tensor:
        """Coordinates of x in the ellipsoid's frame (centre at 0, axes along x, y, z)."""
        x = as_tensor(x)
        b = self._buffers(x.device, x.dtype)
        return (x - b["c"]) @ b["R"]

    def _k0(self, x: Tensorish) -> tuple[torch.Tensor, torch.Tensor]:
        y = self.local(x)
        return (y / self._buffers(y.device, y.dtype)["a"]).norm(dim=-1), y

    def signed_distance(self, x: Tensorish, iters: int = 40) -> torch.Tensor:
        """Exact signed distance (bisection on the Lagrange multiplier, Eberly's method).

        The closest point is found without autograd; the gradient of the result is then the
        wall's unit normal there, as for a true distance function.
        """
        y = self.local(x)
        a = self._buffers(y.device, y.dtype)["a"]
        shape = y.shape[:-1]
        z = y.reshape(-1, 3).abs()
        with torch.no_grad():
            p = self._closest_first_octant(z.detach(), a, iters)
        dist = (z - p).norm(dim=-1)
        inside = (z / a).square().sum(-1) < 1
        return torch.where(inside, -dist, dist).reshape(shape)

    @staticmethod
    def _closest_first_octant(z: torch.Tensor, a: torch.Tensor, iters: int) -> torch.Tensor:
        """Closest wall point to z >= 0 (N, 3), for axes a sorted longest first."""
        a2 = a * a
        # p_i = a_i^2 z_i / (t + a_i^2), where t solves g(t) = sum (a_i z_i / (t + a_i^2))^2
        # = 1; g decreases on t > -a_min^2, and lo / hi below bracket the root.
        lo = -a2[2] + a[2] * z[:, 2]
        hi = torch.maximum(-a2[2] + (a * z).norm(dim=-1), lo)
        for _ in range(iters):
            mid = 0.5 * (lo + hi)
            g = (a * z / (mid[:, None] + a2).clamp_min(1e-30)).square().sum(-1)
            up = g > 1
            lo = torch.where(up, mid, lo)
            hi = torch.where(up, hi, mid)
        t = 0.5 * (lo + hi)
        p = a2 * z / (t[:, None] + a2).clamp_min(1e-30)
        # Degenerate case (z_min ~ 0 deep inside): the last coordinate comes from the surface.
        rest = (p[:, :2] / a[:2]).square().sum(-1)
        p_last = a[2] * (1 - rest).clamp_min(0).sqrt()
        degenerate = (t[:, None] + a2)[:, 2] < 1e-6 * a2[2]
        return torch.cat([p[:, :2], torch.where(degenerate, p_last, p[:, 2]).unsqueeze(1)], 1)

    def in_core(self, x: Tensorish, fraction: float = 0.5) -> torch.Tensor:
        return self._k0(x)[0] < fraction

    def radius_at(self, x: Tensorish) -> torch.Tensor:
        """Distance from the centre to the wall in x's direction."""
        k0, y = self._k0(x)
        r = y.norm(dim=-1)
        return torch.where(k0 > 1e-12, r / k0.clamp_min(1e-12), torch.full_like(r, self.axes[2]))

    def ray_bounds(
        self,
        origins: Tensorish,
        dirs: Tensorish,
        margin: float = 0.25,
        *,
        max_far: float | None = None,
        near_fraction: float = 0.05,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        o, d, dnorm = flat_rays(origins, dirs)
        b = self._buffers(o.device, o.dtype)
        a = b["a"] * (1.0 + margin)
        oy = ((o - b["c"]) @ b["R"]) / a
        dy = (d @ b["R"]) / a
        qa = (dy * dy).sum(-1)
        qb = (oy * dy).sum(-1)
        qc = (oy * oy).sum(-1) - 1
        disc = qb * qb - qa * qc
        root = (-qb + disc.clamp_min(0).sqrt()) / qa
        cap = float(max_far) if max_far is not None else self.far_radii * self.typical_radius
        far = torch.where((disc >= 0) & (root > 0), root, torch.full_like(root, cap))
        far = far.clamp(max=cap)
        return near_far(near_fraction, self.radius_at(o), far, dnorm)

    def _moved(self, s: float, r: np.ndarray, t: np.ndarray) -> EllipsoidPrior:
        return EllipsoidPrior(
            s * r @ self.centre + t, s * self.axes, r @ self.rotation, far_radii=self.far_radii
        )

    def _arrays(self) -> dict[str, np.ndarray]:
        return {"centre": self.centre, "axes": self.axes, "rotation": self.rotation}
