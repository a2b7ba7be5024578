"""Exact ray casting of an implicit scene: where each pixel's ray first meets the wall.

Two ways to the same answer. The reference is sphere tracing with steps that provably stay in
the lumen (|f| over a bound of |grad f| valid in the ball the step sweeps), until the ray crosses
the wall. The fast way lets Embree (open3d) intersect the wall's fine mesh, and accepts that hit
as a bracket only when (a) f changes sign across it and (b) the ray met a copy of the mesh pushed
into the lumen no earlier than the bracket starts, so no part of the true wall can come first;
other rays (silhouettes, grazing) go to the sphere tracer, starting where they met the pushed
copy. Either way the crossing is then refined on f itself (regula falsi in float32 for traced
rays, then two float64 Newton steps, or float64 regula falsi where Newton is not sure): hit points
lie on the true surface to ~1e-7 mm.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
import open3d as o3d

from endopipe.stages.camera import Camera, image_directions
from endopipe.synth.scene import Scene

MIN_STEP = 0.01  # mm: below this the tracer steps anyway and lets the bracket catch the crossing
MAX_ITER = 2000
REFINE_ITER = 24
REFINE_TOL = 5e-4  # mm: float32 bracket width handed to the float64 Newton polish
CHUNK = 32768
OMEGA = 1.6  # over-relaxation of the sphere tracer
F32 = np.float32


Coords = tuple[np.ndarray, np.ndarray, np.ndarray]


def chunked(fn: Callable[..., Any], *arrays: np.ndarray) -> Any:
    """fn over CHUNK-sized slices of the arrays (first axis), outputs concatenated back."""
    n = len(arrays[0])
    outs = [fn(*(a[s : s + CHUNK] for a in arrays)) for s in range(0, max(n, 1), CHUNK)]
    if isinstance(outs[0], tuple):
        return tuple(np.concatenate(k) for k in zip(*outs, strict=True))
    return np.concatenate(outs)


def columns(a: np.ndarray, dtype: type) -> Coords:
    """(N, 3) array -> three contiguous coordinate arrays of `dtype`."""
    x, y, z = np.ascontiguousarray(np.asarray(a, dtype).T)
    return x, y, z


class StepBound:
    """Upper bounds of |grad f| as a function of the radial coordinate, estimated by sampling.

    env[k] bounds |grad f| over every sampled point whose radial coordinate is >= k * bin, times
    a safety factor. A point q with f(q) < 0 may then step |f| / env(radial(q) - Lr |f|): the
    ball of that radius only holds points whose radial coordinate is at least that large.
    """

    BIN = 0.5  # mm

    def __init__(self, scene: Scene, rng: np.random.Generator, samples: int = 200_000) -> None:
        self.radial_lipschitz = scene.radial_lipschitz
        p = scene.sample_interior(rng, samples)
        grad = np.linalg.norm(finite_difference_gradient(scene, p, 1e-3), axis=1)
        r = scene.radial_points(p)
        nbins = int(r.max() / self.BIN) + 2
        idx = np.minimum((r / self.BIN).astype(np.int64), nbins - 1)
        per_bin = np.zeros(nbins)
        np.maximum.at(per_bin, idx, grad)
        # Max over all bins at or beyond k, so that env is valid for "radial >= k * bin".
        self.env = np.maximum(np.maximum.accumulate(per_bin[::-1])[::-1] * 1.25, 1.0)
        self._inv_env = (1.0 / self.env).astype(F32)

    def step(
        self,
        radial: np.ndarray,
        val: np.ndarray,
        clear: np.ndarray | None,
        stretch: float = 1.0,
    ) -> np.ndarray:
        """Safe step length from points with these radial coordinates and f values (< 0).

        For a ball radius cap c |f| (c = 1, 1/2, 1/4) the gradient bound of the radial range
        that ball can reach gives the step min(c |f|, |f| / env): take the best of them, and
        the scene's coarse `clear` bound when that is larger. A deformed scene (`stretch` =
        1 + L of its displacement) reaches rest points up to `stretch` times farther, where f
        may change `stretch` times faster: both bounds shrink by it.
        """
        dist = -val
        best = np.zeros_like(dist)
        top = len(self._inv_env) - 1
        lr = self.radial_lipschitz * stretch
        inv_env = self._inv_env if stretch == 1.0 else self._inv_env * F32(1.0 / stretch)
        for c in (1.0, 0.5, 0.25):
            r_in = radial - (lr * c) * dist
            idx = np.minimum(np.maximum((r_in * (1.0 / self.BIN)).astype(np.int64), 0), top)
            best = np.maximum(best, np.minimum(dist * inv_env[idx], c * dist))
        if clear is not None:
            best = np.maximum(best, clear)
        return np.maximum(best, MIN_STEP)


def finite_difference_gradient(scene: Scene, p: np.ndarray, h: float) -> np.ndarray:
    """Gradient of f at (N, 3) points from a tetrahedral stencil (4 evaluations, error O(h^2)),
    in the points' dtype."""
    x, y, z = columns(p, p.dtype.type)
    g = np.zeros((len(x), 3), dtype=p.dtype)
    for k in _TETRA:
        g += np.outer(scene.f(x + k[0] * h, y + k[1] * h, z + k[2] * h), k)
    return g * (1.0 / (4.0 * h))


_TETRA = np.array([[1, -1, -1], [-1, -1, 1], [-1, 1, -1], [1, 1, 1]], dtype=np.float64)


@dataclass
class _Rays:
    """Structure-of-arrays float32 ray state; `ids` maps back to the caller's ray order."""

    o: list  # three arrays, or three scalars when all rays share one origin
    d: list
    t: np.ndarray
    t_prev: np.ndarray
    ids: np.ndarray

    def take(self, keep: np.ndarray) -> None:
        if np.ndim(self.o[0]):
            self.o = [a[keep] for a in self.o]
        self.d = [a[keep] for a in self.d]
        self.t, self.t_prev, self.ids = self.t[keep], self.t_prev[keep], self.ids[keep]

    def at(self, t: np.ndarray) -> Coords:
        return tuple(o + t * d for o, d in zip(self.o, self.d, strict=True))


def trace(
    scene: Scene,
    bound: StepBound,
    origins: np.ndarray,
    dirs: np.ndarray,
    t_max: float = 600.0,
    t_start: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance along each unit ray to its first wall crossing (NaN where it misses).

    Returns float64 (t, lo, hi): t to ~1e-5 mm from float32 work, and a bracket around it.
    `origins` is (3,) or (N, 3); the points at `t_start` (default 0) must be in the lumen and no
    wall may lie before them. Rays go in chunks of CHUNK: the temporaries of a chunk stay in
    cache, which is 2-3x faster than whole frames at once.
    """
    origins = np.asarray(origins, np.float64)
    t_start = np.zeros(len(dirs)) if t_start is None else t_start
    parts = []
    for s in range(0, len(dirs), CHUNK):
        o = origins if origins.ndim == 1 else origins[s : s + CHUNK]
        t0 = t_start[s : s + CHUNK].astype(F32)
        parts.append(_trace_chunk(scene, bound, o, dirs[s : s + CHUNK], t_max, t0))
    return tuple(np.concatenate(k) for k in zip(*parts, strict=True))


def _trace_chunk(
    scene: Scene,
    bound: StepBound,
    origins: np.ndarray,
    dirs: np.ndarray,
    t_max: float,
    t_start: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Over-relaxed sphere tracing (Keinert et al. 2014) of one chunk of rays.

    Each ray holds a point t known to be in the lumen and its safe radius r. It tries the point
    t + OMEGA r; the try is kept when the safe spheres of both points overlap (no wall can lie
    between them), otherwise the ray falls back to the plain step t + r. A wall is only reported
    from a plain step, so the crossing found is the first one along the ray.
    """
    n = len(dirs)
    o = [F32(v) for v in origins] if origins.ndim == 1 else list(columns(origins, F32))
    rays = _Rays(o, list(columns(dirs, F32)), t_start.copy(), np.zeros(n, F32), np.arange(n))
    r = np.zeros(n, F32)  # rays.t is the safe point, rays.t_prev is unused here
    omega = np.ones(n, F32)
    lo, hi = np.full(n, np.nan, F32), np.full(n, np.nan, F32)
    done = np.zeros(n, dtype=bool)
    for _ in range(MAX_ITER):
        tc = rays.t + omega * r
        pts = rays.at(tc)
        val, radial = scene.f_radial(*pts)
        rc = bound.step(radial, val, scene.clear_ball(*pts, radial), scene.stretch)
        out = tc > t_max
        escaped = scene.escaped(*pts)
        if escaped is not None:
            out |= escaped
        plain = omega == 1
        inside = val < 0
        accept = inside & ~out & (r + rc >= tc - rays.t) & ~done
        crossed = plain & ~inside & ~out & ~done
        hit = np.flatnonzero(crossed)
        lo[rays.ids[hit]], hi[rays.ids[hit]] = rays.t[hit], tc[hit]
        done |= crossed | (plain & out)
        rays.t = np.where(accept, tc, rays.t)
        r = np.where(accept, rc, r)
        omega = np.where(accept, F32(OMEGA), F32(1))
        n_done = int(np.count_nonzero(done))
        if n_done == len(done):
            break
        if n_done > 0.25 * len(done):  # compacting costs a few passes: do it now and then
            keep = np.flatnonzero(~done)
            rays.take(keep)
            r, omega, done = r[keep], omega[keep], done[keep]
    return _refine(scene, o, list(columns(dirs, F32)), lo, hi)


def _refine(scene: Scene, o: list, d: list, lo: np.ndarray, hi: np.ndarray) -> tuple:
    """Illinois (modified regula falsi) on f along each ray inside its bracket [lo, hi]:
    float32 until the bracket is REFINE_TOL wide; rays that are done drop out."""
    n = len(lo)
    idx = np.flatnonzero(np.isfinite(lo))
    rays = _Rays(o, d, t=lo, t_prev=hi, ids=np.arange(n))
    rays.take(idx)
    a, b = rays.t, rays.t_prev  # the bracket: f(a) < 0 <= f(b)
    fa, fb = scene.f(*rays.at(a)), scene.f(*rays.at(b))
    side = np.zeros(len(a), dtype=np.int8)
    ra, rb = a.copy(), b.copy()  # results, per ray in `rays` order
    pos = np.arange(len(a))
    for _ in range(REFINE_ITER):
        open_ = np.flatnonzero(b - a >= REFINE_TOL)
        if len(open_) == 0:
            break
        if len(open_) < len(a):
            rays.take(open_)
            a, b, fa, fb, side, pos = (v[open_] for v in (a, b, fa, fb, side, pos))
        c = a - fa * ((b - a) / (fb - fa))
        c = np.where(np.isfinite(c) & (c > a) & (c < b), c, 0.5 * (a + b))
        fc = scene.f(*rays.at(c))
        inside = fc < 0
        # Illinois: halve the stale end's value when the same end moves twice in a row.
        fb = np.where(inside & (side == -1), 0.5 * fb, fb)
        fa = np.where(~inside & (side == 1), 0.5 * fa, fa)
        a, fa = np.where(inside, c, a), np.where(inside, fc, fa)
        b, fb = np.where(inside, b, c), np.where(inside, fb, fc)
        side = np.where(inside, -1, 1).astype(np.int8)
        ra[pos], rb[pos] = a, b
    t, lo_out, hi_out = (np.full(n, np.nan) for _ in range(3))
    t[idx] = 0.5 * (ra + rb)
    lo_out[idx], hi_out[idx] = ra, rb
    return t, lo_out, hi_out


def polish(
    scene: Scene,
    origin: np.ndarray,
    dirs: np.ndarray,
    t: np.ndarray,
    bracket: tuple[np.ndarray, np.ndarray],
    grad: np.ndarray,
) -> np.ndarray:
    """Float64 finish: two Newton steps along each ray, then regula falsi in float64 for the
    few grazing rays where float32 could not pin the crossing. Hits end within 1e-7 mm of f = 0.
    """
    slope = np.einsum("ij,ij->i", grad, dirs)
    steep = slope > 1e-3
    for _ in range(2):  # the float32 slope is good to ~1%: each step gains two digits
        f = scene.f_points(origin + t[:, None] * dirs)
        delta = np.where(steep, f / np.maximum(slope, 1e-3), 0.0)
        t = np.clip(t - delta, bracket[0] - 1e-3, bracket[1] + 1e-3)
    # A last step under 1e-5 mm leaves an error ~100x smaller; otherwise solve it properly.
    bad = np.flatnonzero(~steep | (np.abs(delta) > 1e-5))
    if len(bad):
        t[bad] = _bisect64(scene, origin, dirs[bad], bracket[0][bad], bracket[1][bad], t[bad])
    return t


def _bisect64(
    scene: Scene,
    origin: np.ndarray,
    dirs: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    guess: np.ndarray,
) -> np.ndarray:
    """Illinois in float64 on a float32 bracket, widened until f64 agrees on its signs (rays
    where it never does keep `guess`)."""
    pad = 1e-3
    a, b = lo - pad, hi + pad
    for _ in range(6):
        fa = scene.f_points(origin + a[:, None] * dirs)
        fb = scene.f_points(origin + b[:, None] * dirs)
        wrong_a, wrong_b = fa >= 0, fb < 0
        if not (wrong_a.any() or wrong_b.any()):
            break
        pad *= 4.0
        a, b = np.where(wrong_a, lo - pad, a), np.where(wrong_b, hi + pad, b)
    valid = (fa < 0) & (fb >= 0)
    side = np.zeros(len(a), dtype=np.int8)
    for _ in range(60):
        c = a - fa * ((b - a) / (fb - fa))
        c = np.where(np.isfinite(c) & (c > a) & (c < b), c, 0.5 * (a + b))
        fc = scene.f_points(origin + c[:, None] * dirs)
        inside = fc < 0
        fb = np.where(inside & (side == -1), 0.5 * fb, fb)
        fa = np.where(~inside & (side == 1), 0.5 * fa, fa)
        a, fa = np.where(inside, c, a), np.where(inside, fc, fa)
        b, fb = np.where(inside, b, c), np.where(inside, fb, fc)
        side = np.where(inside, -1, 1).astype(np.int8)
        if np.max(b - a) < 1e-9:
            break
    return np.where(valid, 0.5 * (a + b), guess)


@dataclass
class FrameGeometry:
    """What one camera sees: z-depth per pixel and, for hit pixels, surface data."""

    depth: np.ndarray  # (H, W) float64 z-depth, 0 where the ray missed
    valid: np.ndarray  # (H, W) bool
    points: np.ndarray  # (M, 3) world hit points of the valid pixels (row-major order)
    normals: np.ndarray  # (M, 3) unit normals facing the lumen
    dist: np.ndarray  # (M,) distance to the camera centre (= light distance)
    cos: np.ndarray  # (M,) n . l, cosine between normal and direction to the light
    fx: float
    origin: np.ndarray  # (3,) camera centre (= light position)
    pixel_angle: np.ndarray | None = None  # (M,) rad per pixel of a distorted lens; else 1 / fx


@lru_cache(maxsize=4)
def _unit_directions(camera_json: str) -> tuple[np.ndarray, np.ndarray]:
    """Unit camera-frame directions of all pixel centres (row-major), and z per unit length,
    for a camera given as JSON (a Camera is not hashable; frames share one camera)."""
    d = image_directions(Camera.model_validate_json(camera_json)).reshape(-1, 3)
    norm = np.linalg.norm(d, axis=1)
    return d / norm[:, None], 1.0 / norm


@lru_cache(maxsize=4)
def _pixel_angles(camera_json: str) -> np.ndarray:
    """Angular size (rad) of every pixel (row-major): the square root of the solid angle its
    unit directions span. A distorted lens squeezes the edges, where one pixel sees more."""
    d, _ = _unit_directions(camera_json)
    camera = Camera.model_validate_json(camera_json)
    d = d.reshape(camera.height, camera.width, 3)
    du, dv = np.gradient(d, axis=1), np.gradient(d, axis=0)
    return np.sqrt(np.linalg.norm(np.cross(du, dv), axis=-1)).ravel()


def camera_rays(intr: Camera, c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera centre, unit world directions of all pixel centres (row-major), z per unit length."""
    d, z_per_t = _unit_directions(intr.model_dump_json())
    # einsum, not @: a BLAS call spawns threads that only contend on a busy 2-core machine.
    return c2w[:3, 3].copy(), np.einsum("nj,ij->ni", d, c2w[:3, :3]), z_per_t


class MeshGuide:
    """The wall's mesh pushed `offset` mm into the lumen, in an Embree scene.

    `error` bounds how far the mesh strays from the true wall (sampled at triangle centres and
    edge midpoints); the push is 3x that, so the pushed mesh separates the lumen from a band that
    contains the whole true wall: a ray cannot meet the wall before it meets the pushed mesh.
    `slack` (mm) pushes it farther, for a wall that moves up to that far from this mesh (a
    deforming scene); such rays then only start the sphere tracer there (no narrow bracket).
    """

    def __init__(
        self, scene: Scene, vertices: np.ndarray, faces: np.ndarray, slack: float = 0.0
    ) -> None:
        self.error = mesh_error(scene, vertices, faces)
        self.slack = float(slack)
        self.offset = max(3.0 * self.error, 0.01) + self.slack
        pushed = vertices + self.offset * vertex_normals(vertices, faces)
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(
            o3d.core.Tensor(pushed.astype(F32)), o3d.core.Tensor(faces.astype(np.uint32))
        )

    def cast(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(t where each ray meets the pushed mesh or inf, cosine of incidence there)."""
        rays = np.concatenate([np.broadcast_to(origin, dirs.shape), dirs], axis=1).astype(F32)
        ans = self._scene.cast_rays(o3d.core.Tensor(rays))
        t = ans["t_hit"].numpy().astype(np.float64)
        cos = -np.einsum("ij,ij->i", ans["primitive_normals"].numpy(), dirs)
        return t, cos


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals, following the faces' winding."""
    tri = vertices[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    vn = np.zeros_like(vertices)
    for k in range(3):
        for corner in range(3):
            vn[:, k] += np.bincount(faces[:, corner], weights=fn[:, k], minlength=len(vertices))
    return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-30)


def mesh_error(scene: Scene, vertices: np.ndarray, faces: np.ndarray, n: int = 100_000) -> float:
    """Largest distance from the true wall of sampled triangle centres and edge midpoints."""
    pick = faces[np.linspace(0, len(faces) - 1, min(n, len(faces))).astype(np.int64)]
    tri = vertices[pick]
    pts = np.concatenate(
        [tri.mean(1), 0.5 * (tri[:, 0] + tri[:, 1]), 0.5 * (tri[:, 1] + tri[:, 2])]
    )
    pts = pts.astype(F32)  # float32 noise (~1e-5 mm) is far below the chord errors measured
    grad = np.linalg.norm(
        chunked(lambda p: finite_difference_gradient(scene, p, 1e-2), pts), axis=1
    )
    return float(np.max(np.abs(chunked(scene.f_points, pts)) / grad))


def trace_frame(
    scene: Scene, bound: StepBound, guide: MeshGuide | None, intr: Camera, c2w: np.ndarray
) -> FrameGeometry:
    """Ray-cast one frame: exact z-depth plus hit points, normals and light geometry."""
    origin, dirs, z_per_t = camera_rays(intr, c2w)
    t, lo, hi = (np.full(len(dirs), np.nan) for _ in range(3))
    todo = np.ones(len(dirs), dtype=bool)
    start = np.zeros(len(dirs))
    if guide is not None:
        a, cos = guide.cast(origin, dirs)
        # No hit on the pushed mesh: the ray cannot reach the wall inside the modelled part.
        todo[~np.isfinite(a)] = False
        start = np.where(np.isfinite(a), a, 0.0)  # no wall before a: the tracer may start there
    if guide is not None and guide.slack == 0.0:
        # The wall lies between offset - error and offset + error behind the pushed mesh (for a
        # locally flat wall); the sign test below rejects the rays for which that is not so.
        inv_cos = 1.0 / np.maximum(cos, 0.05)
        near, far = max(guide.offset - 2.0 * guide.error, 0.0), guide.offset + 2.0 * guide.error
        a, b = a + near * inv_cos, a + far * inv_cos
        idx = np.flatnonzero(np.isfinite(a) & (cos > 0.05))
        fa = _f32_along(scene, origin, dirs[idx], a[idx])
        fb = _f32_along(scene, origin, dirs[idx], b[idx])
        good = (fa < 0) & (fb >= 0)
        idx, fa, fb = idx[good], fa[good].astype(np.float64), fb[good].astype(np.float64)
        # The bracket is narrow (a few times the mesh error): its secant point is close enough
        # for the float64 Newton polish in _geometry to take it from there.
        lo[idx], hi[idx] = a[idx], b[idx]
        t[idx] = a[idx] - fa * (b[idx] - a[idx]) / (fb - fa)
        todo[idx] = False
        # The mesh reaches a little past the modelled part; hits out there are misses.
        gone = scene.escaped(*columns(origin + t[idx, None] * dirs[idx], np.float64))
        if gone is not None:
            t[idx[gone]] = np.nan
    rest = np.flatnonzero(todo)
    if len(rest):
        t[rest], lo[rest], hi[rest] = trace(scene, bound, origin, dirs[rest], t_start=start[rest])
    return _geometry(scene, intr, origin, dirs, z_per_t, t, lo, hi)


def _f32_along(scene: Scene, origin: np.ndarray, dirs: np.ndarray, t: np.ndarray) -> np.ndarray:
    """f in float32 at distances t along rays from one origin."""
    return chunked(lambda p: scene.f_points(p.astype(F32)), origin + t[:, None] * dirs)


def _geometry(
    scene: Scene,
    intr: Camera,
    origin: np.ndarray,
    dirs: np.ndarray,
    z_per_t: np.ndarray,
    t: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
) -> FrameGeometry:
    """Normals (float32 finite differences), the float64 polish of the hits, z-depth."""
    valid = np.isfinite(t)
    dv = dirs[valid]
    p32 = (origin + t[valid, None] * dv).astype(F32)
    grad = chunked(lambda p: finite_difference_gradient(scene, p, 1e-2), p32).astype(np.float64)
    tv = chunked(
        lambda d, t0, a, b, g: polish(scene, origin, d, t0, (a, b), g),
        dv,
        t[valid],
        lo[valid],
        hi[valid],
        grad,
    )
    normals = -grad / np.linalg.norm(grad, axis=1, keepdims=True)
    depth = np.zeros(len(dirs))
    depth[valid] = tv * z_per_t[valid]
    return FrameGeometry(
        depth=depth.reshape(intr.height, intr.width),
        valid=valid.reshape(intr.height, intr.width),
        points=origin + tv[:, None] * dv,
        normals=normals,
        dist=tv,
        cos=np.einsum("ij,ij->i", normals, -dv),
        fx=intr.fx,
        origin=origin,
        pixel_angle=_pixel_angles(intr.model_dump_json())[valid] if intr.distorted else None,
    )
