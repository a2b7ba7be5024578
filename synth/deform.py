"""Deforming anatomy: a smooth displacement field d(x, t) applied inside the implicit surface.

The wall at time t is {x : f(x - d(x, t)) = 0}, with f the rest anatomy's function: still an
exact implicit surface, so the ray caster stays exact. d is small and smooth with a known
Lipschitz bound L (|d(x) - d(y)| <= L |x - y|, L < 1): the map x -> x - d(x) stretches
distances by at most 1 + L, so the tracer's safe steps shrink by that factor (`stretch`) and
the wall moves at most `reach` mm from the rest wall (the mesh guide's extra slack).

breathe: the wall moves out from the anatomy's axis (colon) or centre (cavity) and back, the
radius scaled by about 1 + a sin^2(pi t / T) (rest at t = 0), with a slow non-uniform part so
it is not a pure scale. pull: a patch of wall around a spot is drawn along a direction by a
compact C2 bump, growing then releasing over the clip (a tool's grasp; `tool.py`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from endopipe.synth.scene import CrossSections, Scene

Coords = tuple[np.ndarray, np.ndarray, np.ndarray]
#: max over u of |d/du (1 - u^2)^3|, at u = 1/sqrt(5): the bump profile's Lipschitz constant.
BUMP_SLOPE = 6.0 / np.sqrt(5.0) * 0.8**2
MAX_LIPSCHITZ = 0.7  # beyond it x -> x - d(x) folds too much for a clean surface


class Displacement(ABC):
    """d(x, t) (mm) with its bounds over every time and every point the tracer may visit."""

    kind: str
    lipschitz: float  # bound of |grad d|
    reach: float  # bound of |d|, mm

    @abstractmethod
    def at(self, x: np.ndarray, y: np.ndarray, z: np.ndarray, t: float) -> Coords:
        """(dx, dy, dz) at points, in the points' dtype."""

    def describe(self) -> dict:
        """For gt/synth.json: the kind, its amplitude and what the amplitude means."""
        return {"kind": self.kind, "lipschitz": self.lipschitz, "reach_mm": self.reach}


class Breathe(Displacement):
    """The wall breathes about the scene's axis or centre: d = s(t) m(x) o(x), with o the
    offset from the axis (`Scene.axis_offset`), m = 1 + b sin(k.x + phi) a slow non-uniform
    gain and s(t) = 1 - 1 / (1 + a sin^2(pi t / T)): where m = 1 the radius is scaled by
    exactly 1 + a sin^2(pi t / T)."""

    kind = "breathe"
    NON_UNIFORM = 0.3  # b
    WAVELENGTH = 80.0  # mm, of the non-uniform gain

    def __init__(
        self, scene: Scene, rng: np.random.Generator, amplitude: float, period_s: float
    ) -> None:
        self.scene, self.amplitude, self.period_s = scene, float(amplitude), float(period_s)
        k = rng.normal(size=3)
        self.k = k / np.linalg.norm(k) * (2.0 * np.pi / self.WAVELENGTH)
        self.phase = float(rng.uniform(0.0, 2.0 * np.pi))
        # Rays only test points in the lumen and balls around them no wider than the lumen:
        # twice the widest lumen point sampled bounds how far from the axis d is evaluated.
        radial = scene.radial_points(scene.sample_interior(rng, 20_000))
        self.rho_max = 2.0 * float(radial.max())
        s_max = self.amplitude / (1.0 + self.amplitude)
        b = self.NON_UNIFORM
        k_norm = float(np.linalg.norm(self.k))
        self.lipschitz = s_max * ((1 + b) * scene.radial_lipschitz + b * k_norm * self.rho_max)
        self.reach = s_max * (1 + b) * self.rho_max

    def scale(self, t: float) -> float:
        return 1.0 - 1.0 / (1.0 + self.amplitude * np.sin(np.pi * t / self.period_s) ** 2)

    def at(self, x: np.ndarray, y: np.ndarray, z: np.ndarray, t: float) -> Coords:
        s = self.scale(t)
        ox, oy, oz = self.scene.axis_offset(x, y, z)
        if s == 0.0:
            return ox * 0, oy * 0, oz * 0
        kx, ky, kz = (float(v) for v in self.k)
        g = float(s) * (1.0 + self.NON_UNIFORM * np.sin(x * kx + y * ky + z * kz + self.phase))
        return g * ox, g * oy, g * oz

    def describe(self) -> dict:
        return {
            **super().describe(),
            "amplitude": self.amplitude,
            "amplitude_units": "relative radius change at the peak",
            "period_s": self.period_s,
            "waveform": "radius x (1 + a sin^2(pi t / T)) about the axis (colon) or centre "
            f"(cavity), times 1 + {self.NON_UNIFORM} sin(k.x + phi) (non-uniform part); rest "
            "shape at t = 0",
        }


class Pull(Displacement):
    """A patch of radius `radius` around `spot` drawn along unit `direction` by
    amplitude(t) * bump(|x - spot| / radius): zero until `start` s, then up and back down as
    sin^2 over the rest of the clip (`end` s)."""

    kind = "pull"

    def __init__(
        self,
        spot: np.ndarray,
        direction: np.ndarray,
        amplitude: float,
        radius: float,
        start: float,
        end: float,
    ) -> None:
        self.spot = np.asarray(spot, np.float64)
        self.direction = np.asarray(direction, np.float64) / np.linalg.norm(direction)
        self.amplitude, self.radius = float(amplitude), float(radius)
        self.start, self.end = float(start), float(end)
        self.lipschitz = self.amplitude * BUMP_SLOPE / self.radius
        self.reach = self.amplitude

    def strength(self, t: float) -> float:
        """The pull at time t, mm: 0 before `start`, peak halfway to `end`, 0 again at `end`."""
        if t <= self.start or t >= self.end:
            return 0.0
        return self.amplitude * float(
            np.sin(np.pi * (t - self.start) / (self.end - self.start)) ** 2
        )

    def at(self, x: np.ndarray, y: np.ndarray, z: np.ndarray, t: float) -> Coords:
        a = self.strength(t)
        if a == 0.0:
            return x * 0, y * 0, z * 0
        sx, sy, sz = (float(v) for v in self.spot)
        inv_r2 = 1.0 / self.radius**2
        u2 = ((x - sx) ** 2 + (y - sy) ** 2 + (z - sz) ** 2) * inv_r2
        w = np.maximum(1 - u2, 0)
        w = (a * w * w * w).astype(x.dtype, copy=False)
        dx, dy, dz = (float(v) for v in self.direction)
        return w * dx, w * dy, w * dz

    def moved(self, t: float) -> np.ndarray:
        """Where the wall point at `spot` (at rest) is at time t."""
        return forward(self, self.spot[None], t)[0]

    def describe(self) -> dict:
        return {
            **super().describe(),
            "amplitude": self.amplitude,
            "amplitude_units": "mm, the pulled spot's largest displacement",
            "radius_mm": self.radius,
            "spot": self.spot.tolist(),
            "direction": self.direction.tolist(),
            "start_s": self.start,
            "end_s": self.end,
        }


def forward(disp: Displacement, p: np.ndarray, t: float, iters: int = 60) -> np.ndarray:
    """Where rest points p (N, 3) are at time t: the x with x - d(x, t) = p, by fixed-point
    iteration (a contraction, L < 1), to float64 precision."""
    p = np.asarray(p, np.float64)
    x = p.copy()
    for _ in range(iters):
        d = np.stack(disp.at(*np.ascontiguousarray(x.T), t), -1)
        new = p + d
        if np.max(np.abs(new - x), initial=0.0) < 1e-12:
            return new
        x = new
    return x


class DeformedScene(Scene):
    """A scene at time t: f(x) = f_rest(x - d(x, t)); the radial coordinate is the rest
    point's, against which the rest scene's gradient bound is tabled."""

    def __init__(self, rest: Scene, disp: Displacement, t: float) -> None:
        if disp.lipschitz >= MAX_LIPSCHITZ:
            raise ValueError(f"deformation too steep (Lipschitz {disp.lipschitz:.2f})")
        self.rest, self.disp, self.t = rest, disp, float(t)
        self.name = rest.name
        self.radial_lipschitz = rest.radial_lipschitz
        self.stretch = 1.0 + disp.lipschitz

    def _rest_point(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> Coords:
        dx, dy, dz = self.disp.at(x, y, z, self.t)
        return x - dx, y - dy, z - dz

    def f_radial(
        self, x: np.ndarray, y: np.ndarray, z: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        return self.rest.f_radial(*self._rest_point(x, y, z))

    def escaped(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray | None:
        return self.rest.escaped(x, y, z)

    def clear_ball(
        self, x: np.ndarray, y: np.ndarray, z: np.ndarray, radial: np.ndarray
    ) -> np.ndarray | None:
        """The rest scene's clear ball around the rest point, shrunk by the stretch: the
        map x -> x - d(x) sends a ball of radius r into one of radius (1 + L) r."""
        rz = self._rest_point(x, y, z)[2]
        clear = self.rest.clear_step(rz, radial)
        return None if clear is None else clear * (1.0 / self.stretch)

    def axis_offset(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> Coords:
        return self.rest.axis_offset(x, y, z)

    def sample_interior(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return self.rest.sample_interior(rng, n)

    def mesh(self, hits: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The rest mesh with every vertex moved to time t: vertices stay exactly on the wall
        (f(x) = f_rest(x - d(x)) = f_rest(rest vertex) = 0)."""
        verts, faces = self.rest.mesh(hits)
        moved = np.concatenate(
            [
                forward(self.disp, verts[s : s + 200_000], self.t)
                for s in range(0, len(verts), 200_000)
            ]
        )
        return moved, faces

    def cross_sections(self, hits: np.ndarray) -> CrossSections:
        return self.rest.cross_sections(hits)
