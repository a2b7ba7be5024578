"""Anatomical lumen priors usable from torch (seed §3.3): a tube around a centre curve, or a cavity.

The NeRF regulariser needs three things of the lumen, for many points at once and on the GPU:
a signed distance to the estimated wall (negative inside the lumen), whether a point lies in
the lumen's core (where density should vanish), and near/far bounds for rays cast from inside.

- `TubePrior`: a polyline centre curve with a radius per sample (linear in arc length). A
  voxel grid (~48^3 cells) stores the polyline segment nearest to each cell centre; a query
  projects on that segment's line: two gathers and a few flops per point, distances accurate to
  second order (well under 1 % of the radius on smooth curves). Ends are open by default (the
  first and last segments go on as straight lines: the lumen continues past what was seen).
  `ray_bounds` jumps from local cylinder to local cylinder (exact in one step on a straight
  tube), safeguarded by a bracket: ~30 ms of one CPU thread for the 82k rays of a 320x256 frame.
- `EllipsoidPrior`: a cavity as an ellipsoid (centre, semi-axes, rotation); exact point-to-
  ellipsoid distance by bisection on the Lagrange multiplier, analytic ray intersection.

Both accept torch tensors (or arrays) of shape (..., 3) on any device and return tensors; both
round-trip through `prior.npz` (`save`, `LumenPrior.load`). No pipeline imports: the NeRF stage
and plain scripts use this module alone.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

Tensorish = Any  # torch.Tensor | np.ndarray | sequence

_GRID_CELLS = 48**3  # cells of the nearest-segment grid (int64: 1 MiB)
_CHUNK = 1 << 15  # points per cdist chunk (exact queries)


def _as_tensor(x: Tensorish) -> torch.Tensor:
    t = x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))
    if not t.is_floating_point():
        t = t.to(torch.float32)
    return t


class LumenPrior:
    """Common interface. Distances are in the units of the curve (the cameras' units)."""

    kind: str = "base"

    #: default cap of ray_bounds' far, in multiples of the (median) radius
    far_radii: float = 6.0
    #: how much L_prior may say (the fit's share of SfM depths it explains; 0: no prior)
    weight: float = 1.0
    #: how far the cameras saw SfM points (world units); None: unknown
    reach: float | None = None
    #: the scene's length scale when it is not this prior's radius: a forced prior that fits
    #: badly takes it from the shape that fits (the cavity preset's ellipsoid around a colon is
    #: 2.4x the tube, and grids sized by it were too coarse for the colon's walls)
    unit: float | None = None
    #: how far past the wall sampling must look to reach the SfM points (the wall inflated by
    #: 1 + margin holds `reach_share` of them; 0: unknown). A wall that fits half of C3VD's
    #: points ended a quarter of its rays short of the point they saw.
    margin: float = 0.0
    #: the widest core (as a fraction of the wall, see `in_core`) the SfM points leave empty:
    #: at most `core_share` of them inside (1: not measured, 0: none). C3VD's tube followed the
    #: camera path, and 8% of the points lay in its half-radius core, where a fold juts in.
    core_limit: float = 1.0

    # --- interface ------------------------------------------------------------------------
    def signed_distance(self, x: Tensorish) -> torch.Tensor:
        """(..., 3) -> (...): approximate signed distance to the wall, negative inside."""
        raise NotImplementedError

    def in_core(self, x: Tensorish, fraction: float = 0.5) -> torch.Tensor:
        """(..., 3) -> bool (...): inside the lumen's core (the wall shrunk by `fraction`)."""
        raise NotImplementedError

    def radius_at(self, x: Tensorish) -> torch.Tensor:
        """(..., 3) -> (...): the lumen radius that applies at x."""
        raise NotImplementedError

    def ray_bounds(
        self,
        origins: Tensorish,
        dirs: Tensorish,
        margin: float = 0.25,
        *,
        max_far: float | None = None,
        near_fraction: float = 0.05,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(N,3), (N,3) -> near (N,), far (N,) in units of `dirs` (x = o + t d).

        far: where the ray leaves the wall inflated by (1 + margin), capped at `max_far`
        (default `far_radii` x the median radius); near: `near_fraction` x the radius at the
        origin, and never more than half of far.
        """
        raise NotImplementedError

    @property
    def typical_radius(self) -> float:
        """The scene's length scale (one NeRF scene unit; the mesh's voxels follow it): the
        prior's own radius, unless `unit` says otherwise."""
        return float(self.unit) if self.unit else self.own_radius

    @property
    def own_radius(self) -> float:
        raise NotImplementedError

    def _arrays(self) -> dict[str, np.ndarray]:
        raise NotImplementedError

    # --- persistence ----------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write `prior.npz`: kind, curve samples, radii, ellipsoid parameters."""
        arrays = {
            "kind": np.array(self.kind),
            "far_radii": np.array(self.far_radii),
            "weight": np.array(self.weight),
        }
        if self.reach is not None:
            arrays["reach"] = np.array(self.reach)
        if self.unit is not None:
            arrays["unit"] = np.array(self.unit)
        if self.margin:
            arrays["margin"] = np.array(self.margin)
        if self.core_limit < 1.0:
            arrays["core_limit"] = np.array(self.core_limit)
        arrays.update(self._arrays())
        with open(path, "wb") as fh:  # np.savez would append ".npz" to a path without it
            np.savez(fh, **arrays)

    @staticmethod
    def load(path: str | Path) -> LumenPrior:
        """The prior stored in `prior.npz` (TubePrior, EllipsoidPrior or FreePrior)."""
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
        kind = str(data["kind"])
        far_radii = float(data.get("far_radii", 6.0))
        prior: LumenPrior
        if kind == "tube":
            prior = TubePrior(
                data["points"],
                data["radius"],
                open_ends=bool(data.get("open_ends", True)),
                far_radii=far_radii,
            )
        elif kind == "cavity":
            prior = EllipsoidPrior(
                data["centre"], data["axes"], data["rotation"], far_radii=far_radii
            )
        elif kind == "none":
            prior = FreePrior(
                data["centre"], float(data["scale"]), float(data["reach"]), float(data["depth"])
            )
        else:
            raise ValueError(f"{path}: unknown prior kind {kind!r}")
        prior.weight = float(data.get("weight", 1.0))
        if "reach" in data:
            prior.reach = float(data["reach"])
        if "unit" in data:
            prior.unit = float(data["unit"])
        prior.margin = float(data.get("margin", 0.0))
        prior.core_limit = float(data.get("core_limit", 1.0))
        return prior

    def to(self, device: str | torch.device) -> LumenPrior:
        """Warm the buffers for `device` (queries move them on demand anyway)."""
        self._buffers(torch.device(device), torch.float32)
        return self

    def _buffers(self, device: torch.device, dtype: torch.dtype) -> dict[str, torch.Tensor]:
        raise NotImplementedError


def _flat_rays(
    origins: Tensorish, dirs: Tensorish
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rays as flat (N, 3) origins and unit directions, and the directions' norms (N,)."""
    o = _as_tensor(origins)
    d = _as_tensor(dirs).to(device=o.device, dtype=o.dtype)
    o, d = torch.broadcast_tensors(o, d)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    dnorm = d.norm(dim=-1).clamp_min(1e-12)
    return o, d / dnorm[:, None], dnorm


def _near_far(
    near_fraction: float, radius_o: torch.Tensor, far: torch.Tensor, dnorm: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    far = far.clamp_min(1e-6)
    near = torch.minimum(near_fraction * radius_o, 0.5 * far)
    return near / dnorm, far / dnorm


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Row-wise dot product of (N, 3) tensors (a matrix-vector product: much faster on CPU
    than a reduction over a last axis of 3)."""
    return (a * b) @ a.new_ones(3)


def _cylinder_exit(
    o: torch.Tensor, d: torch.Tensor, foot: torch.Tensor, u: torch.Tensor, radius: torch.Tensor
) -> torch.Tensor:
    """Largest t where the ray o + t d (d unit) meets the infinite cylinder of `radius` around
    the line through `foot` along `u`; inf where it never does (ray parallel to the axis)."""
    a = o - foot
    a = a - _dot(a, u)[:, None] * u
    b = d - _dot(d, u)[:, None] * u
    qa = _dot(b, b)
    qb = _dot(a, b)
    qc = _dot(a, a) - radius * radius
    disc = qb * qb - qa * qc
    root = (disc.clamp_min(0).sqrt() - qb) / qa.clamp_min(1e-12)
    ok = (disc >= 0) & (qa > 1e-12)
    return torch.where(ok, root, torch.full_like(root, torch.inf))


class TubePrior(LumenPrior):
    """A tube of varying radius around a polyline centre curve.

    points (M, 3) and radius (M,) or a scalar; `open_ends`: the end segments go on as straight
    lines (the lumen continues past what was seen); `far_radii`: default cap of ray_bounds' far
    in median radii; `grid=False` skips the acceleration grid (queries are then exact and use
    brute force: fine for a few one-off queries, slow for a training loop).
    """

    kind = "tube"

    def __init__(
        self,
        points: Tensorish,
        radius: Tensorish | float,
        *,
        open_ends: bool = True,
        far_radii: float = 6.0,
        grid: bool = True,
    ) -> None:
        pts = np.asarray(
            points.detach().cpu() if isinstance(points, torch.Tensor) else points, np.float64
        )
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2:
            raise ValueError("TubePrior needs an (M>=2, 3) array of curve points")
        rad = radius.detach().cpu().numpy() if isinstance(radius, torch.Tensor) else radius
        rad = np.broadcast_to(np.asarray(rad, np.float64), (len(pts),)).copy()
        # Drop repeated samples (zero-length segments have no direction).
        keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9])
        pts, rad = pts[keep], rad[keep]
        if len(pts) < 2:
            raise ValueError("TubePrior needs at least two distinct curve points")
        self.points = pts
        self.radius = rad
        seg = np.diff(pts, axis=0)
        self.seg_len = np.linalg.norm(seg, axis=1)
        self.seg_dir = seg / self.seg_len[:, None]
        self.arclength = np.concatenate([[0.0], np.cumsum(self.seg_len)])
        self.open_ends = bool(open_ends)
        self.far_radii = float(far_radii)
        self._cache: dict[tuple[str, torch.dtype], dict[str, torch.Tensor]] = {}
        self._kdtree: Any = None
        self._grid_np: dict[str, np.ndarray] | None = None
        if grid:
            self._grid_np = self._build_grid()
            self._cache.clear()  # buffers cached while building lack the grid

    # --- construction ---------------------------------------------------------------------
    @property
    def length(self) -> float:
        return float(self.arclength[-1])

    @property
    def own_radius(self) -> float:
        return float(np.median(self.radius))

    def _build_grid(self) -> dict[str, np.ndarray]:
        """Per cell of a box around the tube: the polyline segment closest to the cell centre.

        A query projects on that segment's line (unclamped): on a smooth curve sampled finely,
        the error is of order (cell / curvature radius)^2 x distance, far below 1 %.
        """
        pad = 1.5 * float(self.radius.max()) + 1e-6
        lo = self.points.min(0) - pad
        hi = self.points.max(0) + pad
        extent = hi - lo
        h = float((np.prod(extent) / _GRID_CELLS) ** (1.0 / 3.0))
        h = max(h, float(extent.max()) / 256.0, 1e-9)
        shape = np.maximum(np.ceil(extent / h).astype(np.int64), 1)
        axes = [lo[i] + (np.arange(shape[i]) + 0.5) * h for i in range(3)]
        centres = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        seg = self._closest_exact(torch.from_numpy(centres))["seg"].numpy()
        return {"lo": lo, "h": np.array(h), "shape": shape, "seg": seg}

    def _buffers(self, device: torch.device, dtype: torch.dtype) -> dict[str, torch.Tensor]:
        key = (str(device), dtype)
        buf = self._cache.get(key)
        if buf is None:

            def t(a: np.ndarray, dt: torch.dtype = dtype) -> torch.Tensor:
                return torch.as_tensor(np.ascontiguousarray(a)).to(device=device, dtype=dt)

            n_lut = max(1024, 4 * len(self.points))
            s_lut = np.linspace(0.0, self.length, n_lut)
            buf = {
                "points": t(self.points),
                "seg_dir": t(self.seg_dir),
                "seg_len": t(self.seg_len),
                "arclength": t(self.arclength),
                "r_lut": t(np.interp(s_lut, self.arclength, self.radius)),
                "seg_lut": t(
                    np.searchsorted(self.arclength, s_lut, side="right").clip(1, len(self.seg_len))
                    - 1,
                    torch.long,
                ),
                "lut_scale": t(np.array((n_lut - 1) / max(self.length, 1e-12))),
            }
            g = self._grid_np
            if g is not None:
                sh = g["shape"]
                buf.update(
                    lo=t(g["lo"]),
                    inv_h=t(1.0 / g["h"]),
                    shape_m1=t(sh - 1),
                    stride0=torch.tensor(int(sh[1] * sh[2]), device=device),
                    stride1=torch.tensor(int(sh[2]), device=device),
                    grid=t(g["seg"], torch.long),
                )
            self._cache[key] = buf
        return buf

    # --- closest point ----------------------------------------------------------------------
    def closest(
        self, x: Tensorish, *, exact: bool = False, refine: bool = True
    ) -> dict[str, torch.Tensor]:
        """Closest point of the centre curve to each x (..., 3).

        Returns tensors of shape (...): "dist" (to the curve), "s" (arc length of the foot
        point; below 0 / above `length` on the open ends' extensions), "radius" (at s), and of
        shape (..., 3): "foot" (the closest point) and "tangent" (unit, of its segment).
        The grid's local line gives distances to second order (error ~ distance x (cell /
        curvature radius)^2) and s to first order; `refine` re-projects on the segment under
        the first foot point, making s second order too. `exact=True` projects on the
        polyline's segments next to the nearest sample found by brute force (slower; checks).
        """
        x = _as_tensor(x)
        if x.dtype == torch.float16 or x.dtype == torch.bfloat16:
            x = x.float()
        shape = x.shape[:-1]
        flat = x.reshape(-1, 3)
        out = self._closest_flat(flat, exact=exact, refine=refine)
        return {k: v.reshape(*shape, *v.shape[1:]) for k, v in out.items() if k != "seg"}

    def _closest_flat(
        self, x: torch.Tensor, exact: bool = False, refine: bool = False
    ) -> dict[str, torch.Tensor]:
        if exact or self._grid_np is None:
            return self._closest_exact(x)
        b = self._buffers(x.device, x.dtype)
        f = ((x - b["lo"]) * b["inv_h"]).floor_()
        f = torch.minimum(f.clamp_(min=0), b["shape_m1"]).long()
        cell = f[:, 0] * b["stride0"] + f[:, 1] * b["stride1"] + f[:, 2]
        seg = b["grid"].index_select(0, cell)
        s, foot, u = self._project(x, seg, b)
        if refine:
            # The segment under the first foot point: its line is the better local axis (the
            # first projection's s is first-order accurate, distances second-order).
            i = (s * b["lut_scale"]).clamp(0, b["seg_lut"].shape[0] - 1).long()
            s, foot, u = self._project(x, b["seg_lut"].index_select(0, i), b)
        return {
            "dist": _dot(x - foot, x - foot).sqrt(),
            "s": s,
            "radius": self._radius_of_s(s, b),
            "foot": foot,
            "tangent": u,
        }

    def _project(
        self, x: torch.Tensor, seg: torch.Tensor, b: dict[str, torch.Tensor]
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Arc length, foot point and direction of x projected on the lines of segments `seg`."""
        a = b["points"].index_select(0, seg)
        u = b["seg_dir"].index_select(0, seg)
        s0 = b["arclength"].index_select(0, seg)
        along = _dot(x - a, u)
        s = s0 + along
        if not self.open_ends:
            s = s.clamp(0.0, self.length)
            along = s - s0
        return s, torch.addcmul(a, along[:, None], u), u

    def _nearest_vertex(self, x: torch.Tensor) -> torch.Tensor:
        if x.device.type == "cpu":
            if self._kdtree is None:
                from scipy.spatial import cKDTree

                self._kdtree = cKDTree(self.points)
            _, v = self._kdtree.query(x.detach().numpy().astype(np.float64))
            return torch.from_numpy(np.asarray(v, np.int64))
        pts = self._buffers(x.device, x.dtype)["points"]
        v = torch.empty(len(x), dtype=torch.long, device=x.device)
        for a in range(0, len(x), _CHUNK):
            v[a : a + _CHUNK] = torch.cdist(x[a : a + _CHUNK], pts).argmin(1)
        return v

    def _closest_exact(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        b = self._buffers(x.device, x.dtype)
        m = b["points"].shape[0]
        v = self._nearest_vertex(x)
        seg = torch.stack([(v - 1).clamp(0, m - 2), v.clamp(max=m - 2)], 1)  # (N, 2)
        a = b["points"][seg]  # (N, 2, 3)
        u = b["seg_dir"][seg]
        t = ((x[:, None, :] - a) * u).sum(-1)  # (N, 2)
        lo = torch.zeros_like(t)
        hi = b["seg_len"][seg]
        if self.open_ends:
            lo = torch.where(seg == 0, torch.full_like(t, -torch.inf), lo)
            hi = torch.where(seg == m - 2, torch.full_like(t, torch.inf), hi)
        t = torch.maximum(torch.minimum(t, hi), lo)
        foot = a + t[..., None] * u
        d2 = (x[:, None, :] - foot).square().sum(-1)
        k = d2.argmin(1, keepdim=True)
        pick = k.squeeze(1)
        rows = torch.arange(len(x), device=x.device)
        segk = seg[rows, pick]
        s = b["arclength"][segk] + t[rows, pick]
        return {
            "dist": d2.gather(1, k).squeeze(1).clamp_min(0).sqrt(),
            "s": s,
            "radius": self._radius_of_s(s, b),
            "foot": foot[rows, pick],
            "tangent": u[rows, pick],
            "seg": segk,
        }

    def _radius_of_s(self, s: torch.Tensor, b: dict[str, torch.Tensor]) -> torch.Tensor:
        lut = b["r_lut"]
        f = (s * b["lut_scale"]).clamp(0, lut.shape[0] - 1)
        i = f.floor().long().clamp(max=lut.shape[0] - 2)
        w = f - i
        return torch.lerp(lut[i], lut[i + 1], w)

    # --- queries ----------------------------------------------------------------------------
    def nearest_param(self, x: Tensorish) -> torch.Tensor:
        """Arc length along the curve of x's closest curve point (...)."""
        return self.closest(x)["s"]

    def distance_to_curve(self, x: Tensorish) -> torch.Tensor:
        return self.closest(x, refine=False)["dist"]

    def radius_at(self, x: Tensorish) -> torch.Tensor:
        return self.closest(x)["radius"]

    def radius_of_param(self, s: Tensorish) -> torch.Tensor:
        s = _as_tensor(s)
        return self._radius_of_s(s, self._buffers(s.device, s.dtype))

    def signed_distance(self, x: Tensorish) -> torch.Tensor:
        c = self.closest(x, refine=False)
        return c["dist"] - c["radius"]

    def in_core(self, x: Tensorish, fraction: float = 0.5) -> torch.Tensor:
        c = self.closest(x, refine=False)
        return c["dist"] < fraction * c["radius"]

    def ray_bounds(
        self,
        origins: Tensorish,
        dirs: Tensorish,
        margin: float = 0.25,
        *,
        max_far: float | None = None,
        near_fraction: float = 0.05,
        iters: int = 8,
        tol: float = 5e-3,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Near/far of rays leaving the tube inflated to radius x (1 + margin).

        Each step replaces the tube by the straight cylinder around the segment closest to the
        current point and jumps to the ray's exit from it (exact on a straight tube: one step);
        a bracket [inside, outside] with bisection as the safeguard keeps the first exit on
        bends. Rays converge when |distance - inflated radius| < tol x radius and drop out of
        the loop. Rays that stay inside up to `max_far` get far = max_far; rays whose origin is
        outside the inflated tube get the exit from the cylinder at their origin.
        """
        o = _as_tensor(origins)
        d = _as_tensor(dirs).to(device=o.device, dtype=o.dtype)
        if o.dtype == torch.float16 or o.dtype == torch.bfloat16:
            o, d = o.float(), d.float()
        o, d = torch.broadcast_tensors(o, d)
        o, d = o.reshape(-1, 3), d.reshape(-1, 3)
        n = o.shape[0]
        dnorm = _dot(d, d).sqrt().clamp_min(1e-12)
        d = d / dnorm[:, None]
        cap = float(max_far) if max_far is not None else self.far_radii * self.typical_radius
        infl = 1.0 + margin

        # The origin's closest point; one query when all rays share their origin (a frame).
        if n > 1 and bool((o == o[:1]).all()):
            c0 = {k: v.expand(n, *v.shape[1:]) for k, v in self._closest_flat(o[:1]).items()}
        else:
            c0 = self._closest_flat(o)
        r_origin = c0["radius"]
        f0 = c0["dist"] - infl * r_origin
        t1 = _cylinder_exit(o, d, c0["foot"], c0["tangent"], infl * c0["radius"])
        outside0 = f0 > 0
        far = torch.where(t1 > 0, t1, torch.full_like(t1, cap)).clamp(max=cap)

        # Bracketed iteration on the rays whose origin is inside; `idx` are the live rays and
        # `st` their state rows: lo (known inside), f(lo), hi (known outside), f(hi), t (next).
        idx = torch.nonzero(~outside0).squeeze(1)
        oo, dd = o.index_select(0, idx), d.index_select(0, idx)
        t = t1.index_select(0, idx).clamp(max=cap)
        st = torch.stack(
            [torch.zeros_like(t), f0.index_select(0, idx), torch.full_like(t, cap), t * 0, t]
        )
        hi_known = torch.zeros_like(t, dtype=torch.bool)
        for _ in range(iters):
            if idx.numel() == 0:
                break
            lo, f_lo, hi, f_hi, t = st.unbind(0)
            c = self._closest_flat(torch.addcmul(oo, t[:, None], dd))
            f = c["dist"] - infl * c["radius"]
            inside = f <= 0
            lo = torch.where(inside, t, lo)
            f_lo = torch.where(inside, f, f_lo)
            hi = torch.where(inside, hi, t)
            f_hi = torch.where(inside, f_hi, f)
            hi_known = hi_known | ~inside
            done = (f.abs() <= tol * c["radius"]) | (inside & (t >= cap))
            nxt = _cylinder_exit(oo, dd, c["foot"], c["tangent"], infl * c["radius"])
            # A step must land strictly inside the bracket; otherwise bisect (or try the cap).
            bad = ~((nxt > lo) & (nxt < hi))
            mid = torch.where(hi_known, 0.5 * (lo + hi), hi)
            far.index_copy_(0, idx, torch.where(done, t, far.index_select(0, idx)))
            st = torch.stack([lo, f_lo, hi, f_hi, torch.where(bad, mid, nxt)])
            if bool(done.any()):
                keep = torch.nonzero(~done).squeeze(1)
                idx, st = idx.index_select(0, keep), st.index_select(1, keep)
                oo, dd = oo.index_select(0, keep), dd.index_select(0, keep)
                hi_known = hi_known[keep]
        if idx.numel():
            # Unconverged: regula falsi inside the bracket, or the last step if never outside.
            lo, f_lo, hi, f_hi, t = st.unbind(0)
            w = (-f_lo / (f_hi - f_lo).clamp_min(1e-12)).clamp(0, 1)
            last = torch.where(hi_known, lo + w * (hi - lo), torch.maximum(lo, t))
            far.index_copy_(0, idx, last.clamp(max=cap))
        return _near_far(near_fraction, r_origin, far, dnorm)

    def _arrays(self) -> dict[str, np.ndarray]:
        return {
            "points": self.points,
            "radius": self.radius,
            "arclength": self.arclength,
            "open_ends": np.array(self.open_ends),
        }


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
        x = _as_tensor(x)
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
        o, d, dnorm = _flat_rays(origins, dirs)
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
        return _near_far(near_fraction, self.radius_at(o), far, dnorm)

    def _arrays(self) -> dict[str, np.ndarray]:
        return {"centre": self.centre, "axes": self.axes, "rotation": self.rotation}


class FreePrior(LumenPrior):
    """No anatomical prior (`prior: none`, or `auto` when no shape fits the SfM points): no
    wall, no core, rays bounded only by how far the cameras saw points (`reach`). It keeps the
    prior's other job, the scene's length scale (`scale`, one scene unit), so the NeRF, the
    baked surface and the mesh size their grids and steps the same way for every case."""

    kind = "none"

    def __init__(self, centre: Tensorish, scale: float, reach: float, depth: float) -> None:
        self.centre = np.asarray(centre, np.float64).reshape(3)
        self.scale = float(scale)
        self.reach = float(reach)
        self.depth = float(depth)  # median camera-to-point distance (the light's typical r)
        self.weight = 0.0
        self.far_radii = self.reach / max(self.scale, 1e-12)

    @property
    def own_radius(self) -> float:
        return self.scale

    def _buffers(self, device: torch.device, dtype: torch.dtype) -> dict[str, torch.Tensor]:
        return {}

    def signed_distance(self, x: Tensorish) -> torch.Tensor:
        """0 everywhere: every point is as near a possible wall as any other (a band around
        the 'wall' is then all of space)."""
        return torch.zeros(_as_tensor(x).shape[:-1])

    def in_core(self, x: Tensorish, fraction: float = 0.5) -> torch.Tensor:
        return torch.zeros(_as_tensor(x).shape[:-1], dtype=torch.bool)

    def radius_at(self, x: Tensorish) -> torch.Tensor:
        return torch.full(_as_tensor(x).shape[:-1], self.scale)

    def ray_bounds(
        self,
        origins: Tensorish,
        dirs: Tensorish,
        margin: float = 0.25,
        *,
        max_far: float | None = None,
        near_fraction: float = 0.05,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """near: `near_fraction` x scale; far: the reach (past every point the cameras saw)."""
        _, _, dnorm = _flat_rays(origins, dirs)
        far = torch.full_like(dnorm, self.reach)
        return _near_far(near_fraction, torch.full_like(dnorm, self.scale), far, dnorm)

    def _arrays(self) -> dict[str, np.ndarray]:
        return {
            "centre": self.centre,
            "scale": np.array(self.scale),
            "depth": np.array(self.depth),
        }
