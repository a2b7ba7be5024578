"""The scene frame: a similarity from world (camera) units to scene units, and the field's box.

scene = R^T (world - centre) / scale: R aligns the scene's axes with the principal directions of
the camera path (a tube's long axis becomes a grid axis, which suits the VM factorisation), and
one scene unit is one lumen radius of the prior. The box is where the field lives; outside it the
density is zero. Grid coordinates map the box to [-1, 1]^3.

The map to the grid is warped per axis: linear over the core (the camera path's bounding box
grown by `core_pad` radii), logarithmic beyond it, so cells grow with the distance to the
cameras. Depth error is judged relative to depth, and a tube seen down its length reaches far:
the warp spends the grid where the cameras can resolve detail. Being per axis, it keeps the
VM factorisation's planes and lines meaningful.

A still camera's box can be its view's frustum instead (`Frustum`): grid coordinates are the
image's (x / z, y / z) and the log of the depth, so the grid's planes over the image lie on its
pixels at every depth. An axis-aligned box around a frustum spends most of its cells outside
the view near the camera: EndoNeRF's cutting clip got 2-3 pixels a cell at its tissue's depth.
"""

from __future__ import annotations

import numpy as np
import torch

#: The frustum's depth never reaches under this share of its far end (log z is unbounded).
FRUSTUM_NEAREST = 1e-3


class Frustum:
    """One camera's view as the grid's box: q = (x / z, y / z, log z) of a point in the
    camera's frame (p = rotation (x - centre), scene units), q's box [lo, hi]. Points behind
    the camera or outside the box are outside the grid. `depth_nodes`: the depth's nodes as a
    share of the image's wider side's (log depth has no common unit with the image's)."""

    def __init__(self, rotation, centre, lo, hi, depth_nodes: float = 1.0) -> None:
        self.rotation = np.asarray(rotation, np.float64).reshape(3, 3)
        self.centre = np.asarray(centre, np.float64).reshape(3)
        self.lo = np.asarray(lo, np.float64).reshape(3)
        self.hi = np.asarray(hi, np.float64).reshape(3)
        self.depth_nodes = float(depth_nodes)
        self._t: dict[str, tuple[torch.Tensor, ...]] = {}

    def state(self) -> dict:
        s = {k: getattr(self, k).tolist() for k in ("rotation", "centre", "lo", "hi")}
        return {**s, "depth_nodes": self.depth_nodes}

    @property
    def extent(self) -> np.ndarray:
        """Nominal sizes for the grid's nodes an axis: the image's two spans, and the depth's
        `depth_nodes` of the wider one."""
        span = self.hi - self.lo
        return np.array([span[0], span[1], self.depth_nodes * max(span[0], span[1])])

    def to_grid(self, x: torch.Tensor) -> torch.Tensor:
        key = str(x.device)
        if key not in self._t:
            self._t[key] = tuple(
                torch.tensor(v, dtype=torch.float32, device=x.device)
                for v in (self.rotation, self.centre, self.lo, 2.0 / (self.hi - self.lo))
            )
        rot, c, lo, inv = self._t[key]
        p = (x - c) @ rot.T
        z = p[..., 2:3]
        zs = z.clamp_min(FRUSTUM_NEAREST * float(np.exp(self.hi[2])))
        q = torch.cat([p[..., :2] / zs, torch.log(zs)], -1)
        g = (q - lo) * inv - 1.0
        return torch.where(z > 0, g, torch.full_like(g, 2.0))  # behind the camera: outside

    def grid_to_scene_np(self, g: np.ndarray) -> np.ndarray:
        q = (np.asarray(g, np.float64) + 1.0) * (self.hi - self.lo) / 2.0 + self.lo
        z = np.exp(q[..., 2:3])
        p = np.concatenate([q[..., :2] * z, z], -1)
        return p @ self.rotation + self.centre


class SceneBox:
    def __init__(
        self,
        centre: np.ndarray,
        rotation: np.ndarray,
        scale: float,
        lo: np.ndarray,
        hi: np.ndarray,
        core_lo: np.ndarray | None = None,
        core_hi: np.ndarray | None = None,
        soft: float = 1.0,
    ) -> None:
        self.centre = np.asarray(centre, np.float64).reshape(3)
        self.rotation = np.asarray(rotation, np.float64).reshape(3, 3)
        self.scale = float(scale)
        self.lo = np.asarray(lo, np.float64).reshape(3)
        self.hi = np.asarray(hi, np.float64).reshape(3)
        # No warp unless a core is given (the core then covers the box).
        self.core_lo = self.lo.copy() if core_lo is None else np.asarray(core_lo, np.float64)
        self.core_hi = self.hi.copy() if core_hi is None else np.asarray(core_hi, np.float64)
        self.soft = float(soft)
        self._t: dict[str, tuple[torch.Tensor, ...]] = {}
        #: A still camera's view as the grid's box (module docstring); lo / hi then bound
        #: the frustum in the scene frame (the rays' slab bounds).
        self.frustum: Frustum | None = None

    # --- persistence ------------------------------------------------------------------------
    def state(self) -> dict:
        return {
            "frustum": None if self.frustum is None else self.frustum.state(),
            "centre": self.centre.tolist(),
            "rotation": self.rotation.tolist(),
            "scale": self.scale,
            "lo": self.lo.tolist(),
            "hi": self.hi.tolist(),
            "core_lo": self.core_lo.tolist(),
            "core_hi": self.core_hi.tolist(),
            "soft": self.soft,
        }

    @classmethod
    def from_state(cls, s: dict) -> SceneBox:
        box = cls(
            s["centre"],
            s["rotation"],
            s["scale"],
            s["lo"],
            s["hi"],
            s.get("core_lo"),
            s.get("core_hi"),
            s.get("soft", 1.0),
        )
        if s.get("frustum"):
            box.frustum = Frustum(**s["frustum"])
        return box

    # --- transforms -------------------------------------------------------------------------
    @property
    def extent(self) -> np.ndarray:
        """Size of the box in warped units (= scene units inside the core); a frustum's
        nominal sizes (`Frustum.extent`)."""
        if self.frustum is not None:
            return self.frustum.extent
        return self.warp_np(self.hi) - self.warp_np(self.lo)

    @property
    def warped(self) -> bool:
        """Whether the grid is warped anywhere (the core is smaller than the box)."""
        return bool(np.any(self.core_lo > self.lo) or np.any(self.core_hi < self.hi))

    def core_share(self, points: np.ndarray | None) -> float | None:
        """Share of `points` (world) inside the linear core; None without points."""
        if points is None or len(points) == 0:
            return None
        x = self.world_to_scene_np(np.asarray(points, np.float64).reshape(-1, 3))
        return float(np.all((x >= self.core_lo) & (x <= self.core_hi), axis=1).mean())

    def warp_np(self, x: np.ndarray) -> np.ndarray:
        a, b, k = self.core_lo, self.core_hi, self.soft
        x = np.asarray(x, np.float64)
        y = np.where(x > b, b + k * np.log1p(np.maximum(x - b, 0) / k), x)
        return np.where(x < a, a - k * np.log1p(np.maximum(a - x, 0) / k), y)

    def unwarp_np(self, y: np.ndarray) -> np.ndarray:
        """The inverse of `warp_np`."""
        a, b, k = self.core_lo, self.core_hi, self.soft
        y = np.asarray(y, np.float64)
        x = np.where(y > b, b + k * np.expm1(np.maximum(y - b, 0) / k), y)
        return np.where(y < a, a - k * np.expm1(np.maximum(a - y, 0) / k), x)

    def grid_to_world_np(self, g: np.ndarray) -> np.ndarray:
        """[-1, 1]^3 grid coordinates (the field's, `to_grid`) -> world points."""
        if self.frustum is not None:
            return self.scene_to_world_np(self.frustum.grid_to_scene_np(g))
        glo, ghi = self.warp_np(self.lo), self.warp_np(self.hi)
        y = (np.asarray(g, np.float64) + 1.0) * (ghi - glo) / 2.0 + glo
        return self.scene_to_world_np(self.unwarp_np(y))

    def cell_scene(self, longest: int) -> float:
        """Edge of a grid cell inside the core, in scene units, for `longest` nodes."""
        return float(self.extent.max() / max(longest - 1, 1))

    def world_to_scene_np(self, x: np.ndarray) -> np.ndarray:
        return ((np.asarray(x) - self.centre) @ self.rotation) / self.scale

    def scene_to_world_np(self, x: np.ndarray) -> np.ndarray:
        return (np.asarray(x) * self.scale) @ self.rotation.T + self.centre

    def c2w_to_scene(self, c2w: np.ndarray) -> np.ndarray:
        """A camera pose (4x4, world) in the scene frame: rotation R^T Rc, centre mapped."""
        out = np.eye(4)
        out[:3, :3] = self.rotation.T @ np.asarray(c2w)[:3, :3]
        out[:3, 3] = self.world_to_scene_np(np.asarray(c2w)[:3, 3])
        return out

    def _tensors(self, device: torch.device) -> tuple[torch.Tensor, ...]:
        key = str(device)
        if key not in self._t:
            f = torch.float32
            glo, ghi = self.warp_np(self.lo), self.warp_np(self.hi)
            self._t[key] = tuple(
                torch.tensor(v, dtype=f, device=device)
                for v in (
                    self.centre,
                    self.rotation,
                    glo,
                    2.0 / (ghi - glo),
                    self.core_lo,
                    self.core_hi,
                )
            )
        return self._t[key]

    def scene_to_world(self, x: torch.Tensor) -> torch.Tensor:
        c, r = self._tensors(x.device)[:2]
        return (x * self.scale) @ r.T + c

    def world_to_scene(self, x: torch.Tensor) -> torch.Tensor:
        c, r = self._tensors(x.device)[:2]
        return ((x - c) @ r) / self.scale

    def to_grid(self, x: torch.Tensor) -> torch.Tensor:
        """Scene coordinates -> [-1, 1]^3 over the box (warped outside the core, or the
        frustum's)."""
        if self.frustum is not None:
            return self.frustum.to_grid(x)
        _, _, glo, inv, a, b = self._tensors(x.device)
        k = self.soft
        y = torch.where(x > b, b + k * torch.log1p((x - b).clamp_min(0) / k), x)
        y = torch.where(x < a, a - k * torch.log1p((a - x).clamp_min(0) / k), y)
        return (y - glo) * inv - 1.0

    def ray_bounds(
        self, o: torch.Tensor, d: torch.Tensor, near_min: float = 1e-3
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Slab intersection of scene-frame rays with the box: near (>= near_min), far."""
        lo = torch.as_tensor(self.lo, dtype=o.dtype, device=o.device)
        hi = torch.as_tensor(self.hi, dtype=o.dtype, device=o.device)
        inv = 1.0 / torch.where(d.abs() < 1e-9, torch.full_like(d, 1e-9), d)
        t0, t1 = (lo - o) * inv, (hi - o) * inv
        near = torch.minimum(t0, t1).amax(-1).clamp_min(near_min)
        far = torch.maximum(t0, t1).amin(-1)
        return near, torch.maximum(far, near * 1.5)

    # --- construction -----------------------------------------------------------------------
    @classmethod
    def fit(
        cls,
        centres: np.ndarray,
        scale: float,
        points: np.ndarray,
        pad: float = 0.03,
        core_pad: float | None = None,
        soft: float = 1.0,
    ) -> SceneBox:
        """Axes from the camera centres' principal directions; box around `points` (world).

        With `core_pad` (in radii = scene units), the grid is warped outside the camera path's
        bounding box grown by core_pad; `soft` sets how fast the cells grow beyond it."""
        centres = np.asarray(centres, np.float64).reshape(-1, 3)
        centre = centres.mean(0)
        rotation = np.eye(3)
        if len(centres) >= 3:
            _, s, vt = np.linalg.svd(centres - centre, full_matrices=True)
            if s[0] > 1e-9:
                # Principal direction as the scene z axis (the tube's long axis).
                rotation = np.stack([vt[1], vt[2], vt[0]], 1)
                if np.linalg.det(rotation) < 0:
                    rotation[:, 0] = -rotation[:, 0]
        box = cls(centre, rotation, scale, np.zeros(3), np.ones(3))
        pts = box.world_to_scene_np(np.concatenate([np.asarray(points).reshape(-1, 3), centres]))
        lo, hi = pts.min(0), pts.max(0)
        margin = pad * (hi - lo).max()
        lo, hi = lo - margin, hi + margin
        if core_pad is None:
            return cls(centre, rotation, scale, lo, hi)
        cam = box.world_to_scene_np(centres)
        core_lo = np.maximum(cam.min(0) - core_pad, lo)
        core_hi = np.minimum(cam.max(0) + core_pad, hi)
        return cls(centre, rotation, scale, lo, hi, core_lo, core_hi, soft)
