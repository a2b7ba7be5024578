"""Procedural mucosa albedo, fixed to the surface: a solid texture of world position.

Pinkish-red base, low-frequency mottling, a fine grain and thin dark vessels on three scales
(large ones meander, smaller ones join them, so the network looks branched). Every deviation
from the base colour is scaled by `contrast`. Details finer than a pixel are faded by the
pixel's footprint on the wall, so far walls do not alias into noise that no real camera sees.
"""

from __future__ import annotations

import numpy as np

from endopipe.synth.noise import Perlin3D

BASE = np.array([0.72, 0.22, 0.16])  # linear RGB of healthy mucosa
VESSEL = np.log(np.array([0.78, 0.50, 0.60]))  # log-attenuation at a vessel's centre
MOTTLE = np.array([0.30, 0.50, 0.45])  # log-amplitude of mottling per channel
GRAIN = np.array([0.10, 0.16, 0.16])
# (wavelength mm, half width in noise units, darkness) of the vessel scales.
VESSELS = ((9.0, 0.03, 0.9), (4.5, 0.035, 0.6), (2.2, 0.045, 0.4))


def _lod(wavelengths: np.ndarray, footprint: np.ndarray) -> np.ndarray:
    """(K, N): 1 where a feature of this wavelength spans >= 4 pixels, fading to 0 at 2 pixels."""
    return np.clip(wavelengths[:, None] / (2.0 * footprint[None, :]) - 1.0, 0.0, 1.0)


class MucosaTexture:
    """Albedo and glossiness as functions of world points (mm)."""

    def __init__(self, rng: np.random.Generator, contrast: float) -> None:
        self.contrast = contrast
        self.mottle = Perlin3D(rng)
        self.grain = Perlin3D(rng)
        self.warp = Perlin3D(rng)
        self.vessel = Perlin3D(rng)
        self.bump = Perlin3D(rng)
        self.offsets = rng.uniform(0.0, 100.0, (8, 3))

    def _vessels(
        self,
        x: np.ndarray,
        y: np.ndarray,
        z: np.ndarray,
        footprint: np.ndarray,
        patches: np.ndarray,
    ) -> np.ndarray:
        """Vessel strength in [0, 1]: thin lines along zero sets of warped noise."""
        off = self.offsets
        w1 = self.warp(x * 0.1 + off[0, 0], y * 0.1 + off[0, 1], z * 0.1 + off[0, 2])
        w2 = self.warp(x * 0.1 + off[1, 0], y * 0.1 + off[1, 1], z * 0.1 + off[1, 2])
        # Two warp fields bend all three axes: enough to make the lines meander.
        wx, wy, wz = x + 3 * w1, y + 3 * w2, z + 2 * (w1 - w2)
        strength = np.zeros_like(x)
        for k, (wavelength, width, dark) in enumerate(VESSELS):
            s, o = 1.0 / wavelength, off[3 + k]
            n = self.vessel(wx * s + o[0], wy * s + o[1], wz * s + o[2])
            # A pixel averages the line: widen it by the footprint, keep its integral.
            fp = footprint * (0.6 / wavelength)
            w_eff = np.sqrt(width**2 + fp * fp)
            line = (width / w_eff) * np.exp(-((n / w_eff) ** 2))
            if k == len(VESSELS) - 1:  # the finest vessels show only in patches
                line = line * patches
            strength = np.maximum(strength, dark * line)
        return strength

    def albedo(
        self, x: np.ndarray, y: np.ndarray, z: np.ndarray, footprint: np.ndarray
    ) -> np.ndarray:
        """(N,3) linear albedo at points; `footprint` is one pixel's size on the wall (mm)."""
        m0 = self.mottle(x / 8, y / 8, z / 8)
        m1 = self.mottle(x / 4 + 17.31, y / 4 + 17.31, z / 4 + 17.31)
        mottle = (m0 + 0.5 * m1) / 1.5
        grain_w = _lod(1.5 * 0.5 ** np.arange(2), footprint).astype(x.dtype)
        grain = self.grain.fbm(x / 1.5, y / 1.5, z / 1.5, 2, weights=grain_w)
        vessels = self._vessels(x, y, z, footprint, np.clip(m1 * 3 + 0.5, 0, 1))
        log_var = np.outer(mottle, MOTTLE) + np.outer(grain, GRAIN) + np.outer(vessels, VESSEL)
        return np.minimum(BASE * np.exp(self.contrast * log_var), 1.0)

    def glossiness(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Specular strength multiplier in [0.5, 1]: wetter and drier patches of the wall."""
        o = self.offsets[7]
        wet = self.grain(x / 6 + o[0], y / 6 + o[1], z / 6 + o[2])
        return np.clip(0.75 + 0.6 * wet, 0.5, 1.0)

    def micro_normal(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """(N,3) random tilt field (~1 mm scale) for the wet micro-relief seen in highlights."""
        return np.stack([self.bump(x + 31.7 * k, y - 11.3 * k, z + 5.9 * k) for k in range(3)], -1)
