"""Shading: a point light at the camera centre, Lambert plus Blinn-Phong, sRGB-ish gamma, noise.

intensity = exposure * (albedo * max(n.l, 0) + ks * (n.h)^m) / r^2 + ambient * albedo, with the
light at the camera so l = v = h; r is the distance to the camera centre.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from endopipe.synth.raycast import F32, FrameGeometry, chunked, columns
from endopipe.synth.texture import MucosaTexture

LUMA = np.array([0.2126, 0.7152, 0.0722])


@dataclass(frozen=True)
class Lighting:
    """Point light at the camera centre; exposure is fixed for the whole sequence."""

    exposure: float
    ambient: float = 0.02
    specular: bool = True
    shininess: float = 600.0
    specular_strength: float = 3.0  # wet mucosa: small highlights that clip, as in real scopes
    micro_tilt: float = 0.06  # wet micro-relief tilting the normals seen by highlights only
    gamma: float = 2.2


def _radiance(geom: FrameGeometry, texture: MucosaTexture, light: Lighting) -> tuple:
    """Linear albedo, diffuse and specular radiance (before exposure) at the hit points."""
    per_pixel = geom.dist / geom.fx if geom.pixel_angle is None else geom.dist * geom.pixel_angle
    footprint = per_pixel / np.maximum(np.abs(geom.cos), 0.25)
    pts = columns(geom.points, F32)  # texture needs no float64 precision, and is 30x faster
    albedo = chunked(texture.albedo, *pts, footprint.astype(F32)).astype(np.float64)
    cos = np.clip(geom.cos, 0.0, None)
    inv_r2 = 1.0 / geom.dist**2
    diffuse = albedo * (cos * inv_r2)[:, None]
    spec = np.zeros(len(cos))
    if light.specular:
        # Highlights need n.v near 1; only there is the micro-relief worth computing.
        idx = np.flatnonzero(cos > 0.9)
        sub = tuple(c[idx] for c in pts)
        tilt = chunked(texture.micro_normal, *sub).astype(np.float64)
        n = geom.normals[idx]
        tilt -= np.einsum("ij,ij->i", tilt, n)[:, None] * n  # keep it tangential
        n = n + light.micro_tilt * tilt
        v = n / np.linalg.norm(n, axis=1, keepdims=True)
        cos_h = np.clip(_cos_to_camera(geom, idx, v), 0.0, 1.0)
        ks = light.specular_strength * chunked(texture.glossiness, *sub).astype(np.float64)
        spec[idx] = ks * cos_h**light.shininess * inv_r2[idx]
    return albedo, diffuse, spec


def _cos_to_camera(geom: FrameGeometry, idx: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """n.h for the given normals; with the light at the camera h is the direction to it."""
    to_camera = geom.origin - geom.points[idx]
    to_camera /= np.linalg.norm(to_camera, axis=1, keepdims=True)
    return np.einsum("ij,ij->i", normals, to_camera)


def calibrate_exposure(geoms: list[FrameGeometry], texture: MucosaTexture) -> float:
    """Exposure putting the 95th percentile of the brightest channel's diffuse radiance at 0.9
    (linear): near walls are bright but not clipped, as with an endoscope's auto-exposure."""
    peak = []
    for g in geoms:
        _, diffuse, _ = _radiance(g, texture, Lighting(exposure=1.0, specular=False))
        peak.append(diffuse.max(axis=1))
    return float(0.9 / np.percentile(np.concatenate(peak), 95.0))


def shade(
    geom: FrameGeometry,
    texture: MucosaTexture,
    light: Lighting,
    noise_std: float,
    rng: np.random.Generator,
    gain: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """8-bit sRGB-ish image and the mask of pixels where the specular reflection dominates
    (specular radiance above the diffuse luminance, and bright: > 0.15 linear). `gain` (H, W)
    scales the linear light at the sensor (vignetting); the mask is the scene's, without it."""
    h, w = geom.valid.shape
    albedo, diffuse, spec = _radiance(geom, texture, light)
    lin = light.exposure * (diffuse + spec[:, None]) + light.ambient * albedo
    if gain is not None:
        lin = lin * gain[geom.valid][:, None]
    spec_lin = light.exposure * spec
    dominant = (spec_lin > light.exposure * (diffuse * LUMA).sum(axis=1)) & (spec_lin > 0.15)
    img = np.zeros((h * w, 3))
    img[geom.valid.ravel()] = np.clip(lin, 0.0, 1.0) ** (1.0 / light.gamma)
    img = img + rng.normal(0.0, noise_std, img.shape)
    rgb = np.round(np.clip(img, 0.0, 1.0) * 255.0).astype(np.uint8).reshape(h, w, 3)
    mask = np.zeros(h * w, dtype=bool)
    mask[geom.valid.ravel()] = dominant
    return rgb, mask.reshape(h, w)
