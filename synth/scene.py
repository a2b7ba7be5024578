"""The synthetic anatomy as implicit surfaces: a haustrated colon and a stomach-like cavity.

Each scene is a function f(p) of world points (mm): f < 0 in the lumen (air), f = 0 on the wall,
f > 0 in tissue. The renderer ray-casts f exactly; the mesh is the same surface written through
its parametric form, so ground-truth depth and ground-truth mesh describe one and the same wall.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from endopipe.synth.noise import Perlin3D

TWO_PI = 2.0 * np.pi
_DTYPES = (np.float32, np.float64)


@dataclass(frozen=True)
class CrossSections:
    """Points of a centre axis with two unit vectors spanning the plane normal to it there."""

    points: np.ndarray  # (M, 3)
    u: np.ndarray  # (M, 3)
    v: np.ndarray  # (M, 3)


class Scene(ABC):
    """An implicit lumen wall plus what the tracer and the writer need to know about it.

    Points are passed as three coordinate arrays (x, y, z): contiguous columns are several times
    faster than strided (N, 3) views in the tracer's inner loop. Any float dtype works; the
    tracer marches in float32 and polishes hits in float64.
    """

    name: str
    # Lipschitz constant of `radial`, used to bound how far a step may move the radial coordinate.
    radial_lipschitz: float = 1.0
    # How much more than the rest anatomy f may change per mm (a deformed scene, `deform.py`):
    # the tracer divides its safe steps by it.
    stretch: float = 1.0

    @abstractmethod
    def f_radial(
        self, x: np.ndarray, y: np.ndarray, z: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(f, radial) at points. f < 0 inside the lumen, 0 on the wall; radial is the distance
        from the scene's axis or centre, against which the gradient bound of f is tabled."""

    def f(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        return self.f_radial(x, y, z)[0]

    def f_points(self, p: np.ndarray) -> np.ndarray:
        """f at (N, 3) points."""
        x, y, z = np.ascontiguousarray(np.asarray(p).T)
        return self.f(x, y, z)

    def radial_points(self, p: np.ndarray) -> np.ndarray:
        x, y, z = np.ascontiguousarray(np.asarray(p).T)
        return self.f_radial(x, y, z)[1]

    def escaped(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray | None:
        """Rays that left the modelled part of the anatomy (misses); None when none can."""
        return None

    def clear_step(self, z: np.ndarray, radial: np.ndarray) -> np.ndarray | None:
        """Radius of a ball around the points known to hold no wall, from the scene's coarse
        layout (e.g. the narrowest the lumen gets nearby); None when the scene has no such
        bound. Complements the gradient bound, which is weak far from the wall."""
        return None

    def clear_ball(
        self, x: np.ndarray, y: np.ndarray, z: np.ndarray, radial: np.ndarray
    ) -> np.ndarray | None:
        """`clear_step` at points: a deformed scene looks it up at the rest point."""
        return self.clear_step(z, radial)

    @abstractmethod
    def axis_offset(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> tuple:
        """(ox, oy, oz): the offset of points from the scene's axis or centre, 1-Lipschitz up
        to `radial_lipschitz`; the direction the wall breathes along."""

    @abstractmethod
    def sample_interior(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """(N, 3) points spread over the lumen, to estimate how steep f is."""

    @abstractmethod
    def mesh(self, hits: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(vertices, faces) of the wall, faces wound to face the lumen: all of the modelled
        wall, or a part covering at least the given (N, 3) hit points. Vertices lie exactly on
        the wall; a part is a subset of the whole (same vertices)."""

    @abstractmethod
    def cross_sections(self, hits: np.ndarray) -> CrossSections:
        """Centre axis (1 mm spacing) over the seen part, for gt/centerline.json."""


def _bump(u: np.ndarray) -> np.ndarray:
    """Compact C2 bump (1 - u^2)^3 on |u| < 1: a fold profile with no tail to truncate."""
    b = np.maximum(1 - u * u, 0)
    return b * b * b


def _grid_faces(rows: int, cols: int, wrap: bool) -> np.ndarray:
    """Two triangles per cell of a rows x cols vertex grid (columns wrap around when `wrap`)."""
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(cols if wrap else cols - 1), indexing="ij")
    c1 = (c + 1) % cols
    a, b = r * cols + c, r * cols + c1
    d, e = (r + 1) * cols + c, (r + 1) * cols + c1
    tri = np.concatenate([np.stack([a, b, e], -1), np.stack([a, e, d], -1)], axis=0)
    return tri.reshape(-1, 3)


def _orient_towards(vertices: np.ndarray, faces: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Flip the faces' winding when needed so that normals face the lumen (where cameras are)."""
    tri = vertices[faces[: min(len(faces), 2000)]]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    towards = np.einsum("ij,ij->i", n, inside[faces[: len(n), 0]] - tri[:, 0])
    return faces if np.median(towards) > 0 else faces[:, ::-1].copy()


class ColonScene(Scene):
    """A curved tube with slowly varying radius, a mild triangular section and haustral folds.

    The wall is r(z, theta) around the centre curve c(z) = (cx(z), cy(z), z), measured in the
    plane z = const (the curve is gentle: tilt < 0.25 rad, curvature radius > 170 mm). The camera
    advances along +z from z = 0.
    """

    name = "colon"
    FOLD_HALF_WIDTH = 5.0  # mm, half the axial extent of one fold
    AXIS_CORE = 4.0  # mm; inside it the angular terms fade to 0 so f stays Lipschitz on the axis
    FAR = 220.0  # mm of tube modelled beyond the last camera

    def __init__(self, rng: np.random.Generator, z_end: float) -> None:
        lam = rng.uniform(200.0, 300.0, 2)
        c_omega = TWO_PI / lam
        # Curvature of each component is at most 1/250 mm^-1.
        c_amp = rng.uniform(0.6, 1.0, 2) / (250.0 * c_omega**2)
        c_phase = rng.uniform(0.0, TWO_PI, 2)
        self.r_mean = float(rng.uniform(14.5, 16.5))
        r_amp = np.array([rng.uniform(0.05, 0.09), rng.uniform(0.03, 0.06)])
        r_omega = TWO_PI / np.array([rng.uniform(70.0, 110.0), rng.uniform(30.0, 45.0)])
        r_phase = rng.uniform(0.0, TWO_PI, 2)
        tri_amp = rng.uniform(0.05, 0.08)
        tri_phase = rng.uniform(0.0, TWO_PI)
        self.z_min = -15.0  # cameras start at z = 0 looking along +z: nothing behind is seen
        self.z_far = float(z_end) + self.FAR
        gaps = rng.uniform(15.0, 25.0, int((self.z_far - self.z_min + 120.0) / 15.0) + 2)
        fold_z = self.z_min - 60.0 + np.cumsum(gaps)
        k = len(fold_z)
        fold_h = rng.uniform(3.5, 5.5, k)
        fold_wave = rng.uniform(0.5, 2.0, k)
        wave_phase = rng.uniform(0.0, TWO_PI, k)
        # Fold supports (|dz| < half width + wave <= 7 mm) never overlap (gaps >= 15 mm), so
        # the fold nearest to a 1 mm bucket's centre is the only one that can touch the bucket.
        self._bucket0 = self.z_min - 60.0
        centres = self._bucket0 + 0.5 + np.arange(int(fold_z[-1] - self._bucket0))
        nearest = np.abs(centres[:, None] - fold_z[None, :]).argmin(axis=1)
        self._fold_of_bucket = nearest.astype(np.int64)
        params = {
            "c_omega": c_omega,
            "c_amp": c_amp,
            "c_phase": c_phase,
            "r_mean": self.r_mean,
            "r_amp": r_amp,
            "r_omega": r_omega,
            "r_phase": r_phase,
            "tri_amp": tri_amp,
            "tri_c": np.cos(3.0 * tri_phase),
            "tri_s": np.sin(3.0 * tri_phase),
            "fold_z": fold_z,
            "fold_h": fold_h,
            "fold_wave_c": fold_wave * np.cos(wave_phase),
            "fold_wave_s": fold_wave * np.sin(wave_phase),
        }
        self._p = {dt: {k: np.asarray(v, dt) for k, v in params.items()} for dt in _DTYPES}
        self.fold_z = fold_z
        self.radial_lipschitz = float(np.sqrt(1.0 + np.sum((c_amp * c_omega) ** 2)))
        self._min_radius_tables()

    CLEAR_STEPS = (1.0, 2.0, 4.0, 8.0, 16.0)  # mm

    def _min_radius_tables(self) -> None:
        """Narrowest wall radius per 1 mm bucket, and its running minima over windows wide
        enough to hold a ball of each CLEAR_STEPS radius (sampled densely, minus a margin)."""
        nb = len(self._fold_of_bucket)
        z = self._bucket0 + (np.arange(nb * 10) + 0.5) / 10.0
        th = np.linspace(0.0, TWO_PI, 360, endpoint=False)
        per_z = np.min(
            [
                self.wall_radius(z, np.full_like(z, np.cos(a)), np.full_like(z, np.sin(a)))
                for a in th
            ],
            axis=0,
        )
        # Slopes are < 3 mm/mm and samples 0.1 mm apart: 0.3 mm margin covers what lies between.
        per_bucket = per_z.reshape(nb, 10).min(axis=1) - 0.3
        self._clear = []
        for step in self.CLEAR_STEPS:
            k = int(np.ceil(step)) + 1
            padded = np.pad(per_bucket, k, constant_values=0.0)
            win = np.lib.stride_tricks.sliding_window_view(padded, 2 * k + 1).min(axis=1)
            self._clear.append((np.float32(step), win.astype(np.float32)))

    # --- the centre curve -------------------------------------------------------------------
    def _centre_xy(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = self._p[z.dtype.type]
        cx = p["c_amp"][0] * np.sin(p["c_omega"][0] * z + p["c_phase"][0])
        cy = p["c_amp"][1] * np.sin(p["c_omega"][1] * z + p["c_phase"][1])
        return cx, cy

    def center(self, z: np.ndarray) -> np.ndarray:
        z = np.asarray(z, dtype=np.float64)
        cx, cy = self._centre_xy(z)
        return np.stack([cx, cy, z], axis=-1)

    def tangent(self, z: np.ndarray) -> np.ndarray:
        z = np.asarray(z, dtype=np.float64)
        p = self._p[np.float64]
        d = p["c_amp"] * p["c_omega"] * np.cos(np.multiply.outer(z, p["c_omega"]) + p["c_phase"])
        t = np.concatenate([d, np.ones_like(z)[..., None]], axis=-1)
        return t / np.linalg.norm(t, axis=-1, keepdims=True)

    # --- the wall ---------------------------------------------------------------------------
    def wall_radius(self, z: np.ndarray, ex: np.ndarray, ey: np.ndarray) -> np.ndarray:
        """Wall distance from the centre curve at height z in direction (ex, ey).

        On the wall (ex, ey) is a unit vector; near the axis it shrinks to zero, which fades the
        angular terms (they are polynomials in ex, ey) and keeps f's gradient bounded there.
        """
        p = self._p[z.dtype.type]
        r = p["r_mean"] * (
            1
            + p["r_amp"][0] * np.sin(p["r_omega"][0] * z + p["r_phase"][0])
            + p["r_amp"][1] * np.sin(p["r_omega"][1] * z + p["r_phase"][1])
        )
        # cos(3 (theta - phase)) written as Re((ex + i ey)^3 e^{-3i phase}).
        c3 = ex * (ex * ex - 3 * ey * ey)
        s3 = ey * (3 * ex * ex - ey * ey)
        tri = c3 * p["tri_c"] + s3 * p["tri_s"]
        # Folds: crescents, tallest between the section's corners, slightly wavy along z.
        b = (z - self._bucket0).astype(np.int64)
        j = self._fold_of_bucket[np.minimum(np.maximum(b, 0), len(self._fold_of_bucket) - 1)]
        wave = ey * p["fold_wave_c"][j] + ex * p["fold_wave_s"][j]
        u = (z - p["fold_z"][j] - wave) * (1 / self.FOLD_HALF_WIDTH)
        fold = p["fold_h"][j] * (0.7 - 0.3 * tri) * _bump(u)
        return r * (1 + p["tri_amp"] * tri) - fold

    def f_radial(
        self, x: np.ndarray, y: np.ndarray, z: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        cx, cy = self._centre_xy(z)
        dx, dy = x - cx, y - cy
        rho = np.sqrt(dx * dx + dy * dy)
        inv = 1 / np.maximum(rho, self.AXIS_CORE)
        return rho - self.wall_radius(z, dx * inv, dy * inv), rho

    def escaped(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        return (z > self.z_far) | (z < self.z_min)

    def axis_offset(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> tuple:
        """From the centre curve, in the plane z = const."""
        cx, cy = self._centre_xy(z)
        return x - cx, y - cy, z * 0

    def clear_step(self, z: np.ndarray, radial: np.ndarray) -> np.ndarray:
        """Largest CLEAR_STEPS radius whose ball (radial grows by at most Lr times the radius)
        stays inside the narrowest lumen radius over the z-window it spans."""
        b = np.minimum(
            np.maximum((z - self._bucket0).astype(np.int64), 0), len(self._clear[0][1]) - 1
        )
        best = np.zeros_like(radial)
        for step, table in self._clear:
            ok = radial + self.radial_lipschitz * step < table[b]
            best = np.where(ok, step, best)
        return best

    def min_wall_radius(self) -> float:
        """Smallest wall radius over the modelled tube (checked against AXIS_CORE)."""
        z = np.linspace(self.z_min, self.z_far, 4000)
        th = np.linspace(0.0, TWO_PI, 90, endpoint=False)
        zz, tt = np.meshgrid(z, th, indexing="ij")
        return float(self.wall_radius(zz.ravel(), np.cos(tt).ravel(), np.sin(tt).ravel()).min())

    def sample_interior(self, rng: np.random.Generator, n: int) -> np.ndarray:
        z = rng.uniform(self.z_min, self.z_far, n)
        rho = self.r_mean * 1.3 * np.sqrt(rng.uniform(0.0, 1.0, n))
        th = rng.uniform(0.0, TWO_PI, n)
        c = self.center(z)
        p = np.stack([c[:, 0] + rho * np.cos(th), c[:, 1] + rho * np.sin(th), z], -1)
        return p[self.f_points(p) < 0]

    def _z_range(self, hits: np.ndarray, margin: float) -> tuple[float, float]:
        return float(hits[:, 2].min() - margin), float(hits[:, 2].max() + margin)

    RING_DZ = 0.2  # mm between mesh rings
    RING_VERTICES = 512

    def mesh(self, hits: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Rings every 0.2 mm of z on a fixed grid, 512 vertices each (chord error < 0.01 mm)."""
        z0, z1 = (self.z_min, self.z_far) if hits is None else self._z_range(hits, 1.0)
        k0 = int(np.floor(max(z0, self.z_min) / self.RING_DZ))
        k1 = int(np.ceil(min(z1, self.z_far) / self.RING_DZ))
        z = np.arange(k0, k1 + 1) * self.RING_DZ
        th = np.linspace(0.0, TWO_PI, self.RING_VERTICES, endpoint=False)
        zz, tt = np.meshgrid(z, th, indexing="ij")
        ex, ey = np.cos(tt).ravel(), np.sin(tt).ravel()
        r = self.wall_radius(zz.ravel(), ex, ey)
        c = self.center(zz.ravel())
        verts = np.stack([c[:, 0] + r * ex, c[:, 1] + r * ey, zz.ravel()], -1)
        faces = _grid_faces(len(z), len(th), wrap=True)
        return verts, _orient_towards(verts, faces, self.center(verts[:, 2]))

    def cross_sections(self, hits: np.ndarray) -> CrossSections:
        z0, z1 = self._z_range(hits, 0.0)
        z = np.arange(np.ceil(z0), np.floor(z1) + 1.0)
        t = self.tangent(z)
        u = np.cross(t, np.array([0.0, 1.0, 0.0]))
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        return CrossSections(points=self.center(z), u=u, v=np.cross(t, u))


class CavityScene(Scene):
    """A star-shaped cavity around the origin: an irregular ellipsoid (long axis x) with rugae.

    The wall is at |p| = R(p/|p|); rugae are ridges along zero lines of a noise field stretched
    along x, so they run mostly along the long axis, meander, merge and fade, as in a stomach.
    """

    name = "cavity"
    CANON = 45.0  # mm: radius at which directions are turned into noise coordinates

    def __init__(self, rng: np.random.Generator) -> None:
        self.axes = np.array([rng.uniform(48, 58), rng.uniform(38, 46), rng.uniform(32, 40)])
        v = rng.normal(size=(5, 3))
        params = {
            "inv_axes": 1.0 / self.axes,
            "irr_dir": v / np.linalg.norm(v, axis=1, keepdims=True),
            "irr_freq": rng.uniform(1.5, 3.5, 5),
            "irr_phase": rng.uniform(0.0, TWO_PI, 5),
            "irr_amp": rng.uniform(0.015, 0.035, 5),
            # Noise cells per mm: ridges ~3x longer along the long axis than across it.
            "rugae_scale": self.CANON * np.array([1.0 / 60.0, 1.0 / 20.0, 1.0 / 20.0]),
            "rugae_offset": rng.uniform(0.0, 200.0, 3),
        }
        self._p = {dt: {k: np.asarray(v, dt) for k, v in params.items()} for dt in _DTYPES}
        self.rugae = Perlin3D(rng)
        self.rugae_height = float(rng.uniform(2.5, 3.5))
        self.rugae_width = 0.2  # in noise units
        # Narrowest wall radius from a ~1 degree grid of directions (samples <= 0.8 mm apart on
        # the wall; slopes < 3 mm/mm): a 2 mm margin covers what lies between samples.
        a, ph = np.meshgrid(np.linspace(0, np.pi, 181), np.linspace(0, TWO_PI, 360), indexing="ij")
        d = np.stack([np.cos(a), np.sin(a) * np.cos(ph), np.sin(a) * np.sin(ph)], -1).reshape(-1, 3)
        self.min_radius = float(self.wall_radius(*np.ascontiguousarray(d.T)).min()) - 2.0

    def wall_radius(self, dx: np.ndarray, dy: np.ndarray, dz: np.ndarray) -> np.ndarray:
        """R(d) for unit directions d = (dx, dy, dz)."""
        p = self._p[dx.dtype.type]
        ia, ib, ic = p["inv_axes"]
        e = 1 / np.sqrt((dx * ia) ** 2 + (dy * ib) ** 2 + (dz * ic) ** 2)
        irr = np.zeros_like(dx)
        for k in range(len(p["irr_amp"])):
            v = p["irr_dir"][k]
            arg = (dx * v[0] + dy * v[1] + dz * v[2]) * p["irr_freq"][k] + p["irr_phase"][k]
            irr += p["irr_amp"][k] * np.sin(arg)
        sx, sy, sz = p["rugae_scale"]
        ox, oy, oz = p["rugae_offset"]
        ridge = _bump(self.rugae(dx * sx + ox, dy * sy + oy, dz * sz + oz) / self.rugae_width)
        # Rugae are taller in some regions than others: a slow modulation of their height.
        v, w = p["irr_dir"][0], p["irr_dir"][1]
        strength = 0.7 + 0.15 * (
            np.sin((dx * v[2] + dy * v[0] + dz * v[1]) * 2.3 + p["irr_phase"][2])
            + np.sin((dx * w[1] + dy * w[2] + dz * w[0]) * 3.1 + p["irr_phase"][3])
        )
        return e * (1 + irr) - self.rugae_height * strength * ridge

    def f_radial(
        self, x: np.ndarray, y: np.ndarray, z: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        r = np.sqrt(x * x + y * y + z * z)
        # At the centre any direction will do; +x keeps f finite there.
        inv = 1 / np.maximum(r, 1e-6)
        dx = np.where(r > 1e-6, x * inv, 1)
        return r - self.wall_radius(dx, y * inv, z * inv), r

    def clear_step(self, z: np.ndarray, radial: np.ndarray) -> np.ndarray:
        """Every point closer to the centre than the narrowest wall radius is in the lumen."""
        return self.min_radius - radial

    def axis_offset(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> tuple:
        """From the centre."""
        return x, y, z

    def sample_interior(self, rng: np.random.Generator, n: int) -> np.ndarray:
        p = rng.uniform(-1.0, 1.0, (n, 3)) * self.axes * 1.2
        p = p[np.linalg.norm(p, axis=1) > 1.0]
        return p[self.f_points(p) < 0]

    def mesh(self, hits: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The whole closed wall: 600 rings about the x axis, 1200 vertices each, two poles."""
        if getattr(self, "_mesh", None) is None:
            self._mesh = self._build_mesh()
        return self._mesh

    def _build_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        n_a, n_p = 600, 1200
        a = np.linspace(0.0, np.pi, n_a + 2)[1:-1]
        ph = np.linspace(0.0, TWO_PI, n_p, endpoint=False)
        aa, pp = np.meshgrid(a, ph, indexing="ij")
        d = np.stack([np.cos(aa), np.sin(aa) * np.cos(pp), np.sin(aa) * np.sin(pp)], -1)
        d = np.concatenate([d.reshape(-1, 3), [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]])
        verts = d * self.wall_radius(*np.ascontiguousarray(d.T))[:, None]
        faces = [_grid_faces(n_a, n_p, wrap=True)]
        top, bottom, ring = n_a * n_p, n_a * n_p + 1, np.arange(n_p)
        faces.append(np.stack([np.full(n_p, top), (ring + 1) % n_p, ring], -1))
        last = (n_a - 1) * n_p
        faces.append(np.stack([np.full(n_p, bottom), last + ring, last + (ring + 1) % n_p], -1))
        faces = np.concatenate(faces)
        return verts, _orient_towards(verts, faces, np.zeros_like(verts))

    def cross_sections(self, hits: np.ndarray) -> CrossSections:
        x = np.arange(-np.floor(0.7 * self.axes[0]), np.floor(0.7 * self.axes[0]) + 1.0)
        pts = np.stack([x, np.zeros_like(x), np.zeros_like(x)], -1)
        u = np.tile([0.0, 1.0, 0.0], (len(x), 1))
        v = np.tile([0.0, 0.0, 1.0], (len(x), 1))
        return CrossSections(points=pts, u=u, v=v)
