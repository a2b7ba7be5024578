"""Seeded 3D gradient noise (Ken Perlin's improved noise), vectorised over point arrays.

Both the cavity's rugal folds and the mucosa texture are built from it; being a pure function of
position, anything made from it stays fixed to the surface and is reproducible from the seed.
"""

from __future__ import annotations

import numpy as np

# The 12 cube-edge gradients of improved noise, padded to 16 so that `hash & 15` indexes them.
_GRADS = np.array(
    [
        [1, 1, 0], [-1, 1, 0], [1, -1, 0], [-1, -1, 0],
        [1, 0, 1], [-1, 0, 1], [1, 0, -1], [-1, 0, -1],
        [0, 1, 1], [0, -1, 1], [0, 1, -1], [0, -1, -1],
        [1, 1, 0], [-1, 1, 0], [0, -1, 1], [0, -1, -1],
    ],
    dtype=np.float64,
)  # fmt: skip


def _fade(t: np.ndarray) -> np.ndarray:
    """Quintic fade: C2 across lattice cells, so normals from noise-built surfaces are smooth."""
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


class Perlin3D:
    """Improved Perlin noise in [-1, 1] with a permutation drawn from `rng` (period 256 cells).

    Works in the dtype of its input: float32 for speed while marching and texturing, float64
    where the surface must be exact.
    """

    def __init__(self, rng: np.random.Generator) -> None:
        perm = rng.permutation(256).astype(np.int64)
        self._perm = np.concatenate([perm, perm])
        self._grads = {dt: _GRADS.T.astype(dt) for dt in (np.float32, np.float64)}

    def __call__(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Noise at points given as three coordinate arrays, in lattice units."""
        gx, gy, gz = self._grads[x.dtype.type]
        perm = self._perm
        fx, fy, fz = np.floor(x), np.floor(y), np.floor(z)
        ix, iy, iz = (
            fx.astype(np.int64) & 255,
            fy.astype(np.int64) & 255,
            fz.astype(np.int64) & 255,
        )
        x, y, z = x - fx, y - fy, z - fz
        u, v, w = _fade(x), _fade(y), _fade(z)
        a = perm[ix] + iy
        b = perm[ix + 1] + iy
        aa, ab = perm[a] + iz, perm[a + 1] + iz
        ba, bb = perm[b] + iz, perm[b + 1] + iz

        def grad(h: np.ndarray, dx: np.ndarray, dy: np.ndarray, dz: np.ndarray) -> np.ndarray:
            h = h & 15
            return gx[h] * dx + gy[h] * dy + gz[h] * dz

        x1, y1, z1 = x - 1, y - 1, z - 1
        n000, n100 = grad(perm[aa], x, y, z), grad(perm[ba], x1, y, z)
        n010, n110 = grad(perm[ab], x, y1, z), grad(perm[bb], x1, y1, z)
        n001, n101 = grad(perm[aa + 1], x, y, z1), grad(perm[ba + 1], x1, y, z1)
        n011, n111 = grad(perm[ab + 1], x, y1, z1), grad(perm[bb + 1], x1, y1, z1)
        nx00 = n000 + u * (n100 - n000)
        nx10 = n010 + u * (n110 - n010)
        nx01 = n001 + u * (n101 - n001)
        nx11 = n011 + u * (n111 - n011)
        nxy0 = nx00 + v * (nx10 - nx00)
        nxy1 = nx01 + v * (nx11 - nx01)
        return nxy0 + w * (nxy1 - nxy0)

    def fbm(
        self,
        x: np.ndarray,
        y: np.ndarray,
        z: np.ndarray,
        octaves: int,
        weights: np.ndarray | None = None,
    ) -> np.ndarray:
        """Fractal sum of `octaves` octaves (frequency x2, amplitude /2), normalised to ~[-1, 1].

        `weights` (octaves, N) fades octaves per point, e.g. those finer than a pixel.
        """
        total = np.zeros_like(x)
        amp, norm = 1.0, 0.0
        for k in range(octaves):
            # Offset each octave so that lattice points of different octaves do not line up.
            s, o = 2.0**k, 17.31 * k
            n = self(x * s + o, y * s + o, z * s + o)
            total += amp * (n if weights is None else n * weights[k])
            norm += amp
            amp *= 0.5
        return total / norm
