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
"""

from __future__ import annotations

import numpy as np
import torch


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

    # --- persistence ------------------------------------------------------------------------
    def state(self) -> dict:
        return {
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
        return cls(
            s["centre"],
            s["rotation"],
            s["scale"],
            s["lo"],
            s["hi"],
            s.get("core_lo"),
            s.get("core_hi"),
            s.get("soft", 1.0),
        )

    # --- transforms -------------------------------------------------------------------------
    @property
    def extent(self) -> np.ndarray:
        """Size of the box in warped units (= scene units inside the core)."""
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
        glo, ghi = self.warp_np(self.lo), self.warp_np(self.hi)
        y = (np.asarray(g, np.float64) + 1.0) * (ghi - glo) / 2.0 + glo
        return self.scene_to_world_np(self.unwarp_np(y))

    def cell_world_at(self, points: np.ndarray, longest: int) -> np.ndarray:
        """The grid's cell edge at world `points` (N, 3), in world units, for `longest` nodes
        along the box's longest warped side: the largest over the three axes (a warped axis's
        cells grow with the distance beyond the core)."""
        x = self.world_to_scene_np(np.asarray(points, np.float64).reshape(-1, 3))
        a, b, k = self.core_lo, self.core_hi, self.soft
        beyond = np.maximum(np.maximum(a - x, x - b), 0.0)
        stretch = (k + beyond) / k  # d(scene) / d(warped): 1 inside the core
        return (self.cell_scene(longest) * stretch).max(1) * self.scale

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
        """Scene coordinates -> [-1, 1]^3 over the box (warped outside the core)."""
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
        view: np.ndarray | None = None,
        seen: np.ndarray | None = None,
        seen_share: float = 0.9,
        seen_soft: float = 0.25,
    ) -> SceneBox:
        """Axes from the camera centres' principal directions (and the cameras' mean optical
        axis `view`, when they look sideways); box around `points` (world).

        With `core_pad` (in radii = scene units), the grid is warped outside the camera path's
        bounding box grown by core_pad; with the surface the cameras saw (`seen`, world points:
        the SfM points), outside the box holding the middle `seen_share` of them on every axis,
        grown by a tenth. `soft` sets how fast the cells grow beyond the core (they double
        every `soft` scene units); with `seen`, every `seen_soft` of the core's longest side,
        so the far space the box reaches (a tube's open ends, 12 radii) takes a bounded share
        of the nodes: with the camera path's `soft` of 2 radii the real Hamlyn wall's core got
        a sixth of them."""
        centres = np.asarray(centres, np.float64).reshape(-1, 3)
        centre = centres.mean(0)
        rotation = scene_axes(centres - centre, view)
        box = cls(centre, rotation, scale, np.zeros(3), np.ones(3))
        pts = box.world_to_scene_np(np.concatenate([np.asarray(points).reshape(-1, 3), centres]))
        lo, hi = pts.min(0), pts.max(0)
        margin = pad * (hi - lo).max()
        lo, hi = lo - margin, hi + margin
        if core_pad is None and seen is None:
            return cls(centre, rotation, scale, lo, hi)
        if seen is not None:
            x = box.world_to_scene_np(np.asarray(seen, np.float64).reshape(-1, 3))
            tail = 50.0 * (1.0 - seen_share)
            core_lo, core_hi = np.percentile(x, tail, axis=0), np.percentile(x, 100 - tail, axis=0)
            grow = 0.1 * (core_hi - core_lo).max()
            core_lo, core_hi = core_lo - grow, core_hi + grow
            soft = seen_soft * float((core_hi - core_lo).max())
        else:
            cam = box.world_to_scene_np(centres)
            core_lo, core_hi = cam.min(0) - core_pad, cam.max(0) + core_pad
        lo, hi = np.minimum(lo, core_lo), np.maximum(hi, core_hi)
        return cls(centre, rotation, scale, lo, hi, core_lo, core_hi, soft)


def scene_axes(offsets: np.ndarray, view: np.ndarray | None = None) -> np.ndarray:
    """The scene's axes (columns, world) from the camera centres' offsets from their mean: the
    path's principal direction as z (a tube's long axis; the VM grid's lines follow it). A
    camera that looks sideways of its path (a laparoscope panning over a wall, |view . z| under
    0.7) gets x along its mean optical axis `view`, so the wall it sees lies in the yz plane of
    the grid: a texture on a plane at an angle to every grid plane needs many VM components,
    one in a grid plane needs one (the real Hamlyn clip's wall lay 33 degrees off)."""
    rotation = np.eye(3)
    if len(offsets) < 3:
        return rotation
    _, s, vt = np.linalg.svd(offsets, full_matrices=True)
    if s[0] <= 1e-9:  # a camera that stands still: the world's axes
        return rotation
    rotation = np.stack([vt[1], vt[2], vt[0]], 1)
    z = rotation[:, 2]
    if view is not None and np.linalg.norm(view) > 0:
        v = np.asarray(view, np.float64) / np.linalg.norm(view)
        if abs(float(v @ z)) < 0.7:
            x = v - (v @ z) * z
            x /= np.linalg.norm(x)
            rotation = np.stack([x, np.cross(z, x), z], 1)
    if np.linalg.det(rotation) < 0:
        rotation[:, 0] = -rotation[:, 0]
    return rotation
