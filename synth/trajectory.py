"""Camera paths: smooth, seeded, about 1 mm of travel per frame (or `step_mm`), poses as OpenCV
c2w; a recording may stand still at some frames (pauses).

A path is a smooth curve of a parameter tau; frames are placed on it by arc length with a slowly
varying speed, so the distance travelled is controlled exactly whatever the curve's shape.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from endopipe.stages.camera import look_at
from endopipe.synth.scene import CavityScene, ColonScene

STEP_MM = 1.0


def _speeds(
    frames: int, rng: np.random.Generator, step_mm: float = STEP_MM, still: np.ndarray | None = None
) -> np.ndarray:
    """Arc length of each frame: about `step_mm` per frame, +-25 % slowly varying speed; no
    step into a frame where `still` (the camera stands where it was the frame before)."""
    period = rng.uniform(30.0, 50.0)
    phase = rng.uniform(0.0, 2.0 * np.pi)
    i = np.arange(1, frames)
    ds = step_mm * (1.0 + 0.25 * np.sin(2.0 * np.pi * i / period + phase))
    if still is not None:
        ds = np.where(still[1:], 0.0, ds)
    return np.concatenate([[0.0], np.cumsum(ds)])


def _taus_at(curve: Callable[[np.ndarray], np.ndarray], s: np.ndarray) -> np.ndarray:
    """Parameters tau at which the curve's arc length from tau = 0 equals s (mm)."""
    tau = np.linspace(0.0, 2.0 * s[-1] + 10.0, int(40 * (2.0 * s[-1] + 10.0)) + 2)
    seg = np.linalg.norm(np.diff(curve(tau), axis=0), axis=1)
    length = np.concatenate([[0.0], np.cumsum(seg)])
    if length[-1] < s[-1]:
        raise ValueError("camera curve too slow for the requested path length")
    return np.interp(s, length, tau)


def _roll(c2w: np.ndarray, angle: float) -> np.ndarray:
    """Rotate the camera about its optical axis by `angle` radians."""
    c, s = np.cos(angle), np.sin(angle)
    out = c2w.copy()
    out[:3, :3] = c2w[:3, :3] @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return out


def _wave(rng: np.random.Generator, amp: tuple[float, float], period: tuple[float, float]):
    """A random sinusoid of tau with amplitude and period drawn from the given ranges."""
    a, w, ph = rng.uniform(*amp), 2.0 * np.pi / rng.uniform(*period), rng.uniform(0, 2 * np.pi)
    return lambda tau: a * np.sin(w * np.asarray(tau) + ph)


def colon_poses(
    scene: ColonScene,
    frames: int,
    rng: np.random.Generator,
    step_mm: float = STEP_MM,
    still: np.ndarray | None = None,
) -> np.ndarray:
    """Advance along +z from z = 0 near the centre line, looking 25 mm ahead down the lumen.

    Lateral wobble ~2 mm, view-direction wobble ~5 deg, roll +-10..20 deg plus a slow drift.
    """
    ox, oy = _wave(rng, (1.5, 2.5), (35, 60)), _wave(rng, (1.5, 2.5), (35, 60))
    tx, ty = _wave(rng, (1.5, 2.5), (25, 45)), _wave(rng, (1.5, 2.5), (25, 45))
    roll_wave = _wave(rng, (np.radians(10), np.radians(20)), (60, 100))
    roll_rate = np.radians(rng.uniform(-0.3, 0.3))

    def eye(z: np.ndarray) -> np.ndarray:
        return scene.center(z) + np.stack([ox(z), oy(z), np.zeros_like(z)], -1)

    zs = _taus_at(eye, _speeds(frames, rng, step_mm, still))
    poses = []
    for z in zs:
        target = scene.center(z + 25.0) + np.array([tx(z), ty(z), 0.0])
        c2w = look_at(eye(np.array(z)), target, np.array([0.0, -1.0, 0.0]))
        poses.append(_roll(c2w, roll_wave(z) + roll_rate * z))
    return np.stack(poses)


def cavity_poses(
    scene: CavityScene,
    frames: int,
    rng: np.random.Generator,
    step_mm: float = STEP_MM,
    still: np.ndarray | None = None,
) -> np.ndarray:
    """Circle the long (x) axis 10-14 mm off it, swaying along x, looking out at the wall.

    The view leans ~40 deg ahead along the circling direction, sways +-25 deg along x and rolls.
    """
    a = scene.axes[0]
    r0 = rng.uniform(10.0, 14.0)
    sign = rng.choice([-1.0, 1.0])
    psi0 = rng.uniform(0.0, 2.0 * np.pi)
    x_amp, x_ph = 0.35 * a, rng.uniform(0.0, 2.0 * np.pi)
    r_wave = _wave(rng, (1.5, 2.5), (70, 100))
    lean = _wave(rng, (np.radians(5), np.radians(10)), (120, 160))
    sway = _wave(rng, (np.radians(15), np.radians(25)), (150, 220))
    roll_wave = _wave(rng, (np.radians(8), np.radians(15)), (200, 300))

    def psi(tau: np.ndarray) -> np.ndarray:
        return psi0 + sign * 0.6 * np.asarray(tau) / r0

    def eye(tau: np.ndarray) -> np.ndarray:
        x = x_amp * np.sin(0.8 * np.asarray(tau) / x_amp + x_ph)
        r = r0 + r_wave(tau)
        return np.stack([x, r * np.cos(psi(tau)), r * np.sin(psi(tau))], -1)

    taus = _taus_at(eye, _speeds(frames, rng, step_mm, still))
    poses = []
    for tau in taus:
        ps = psi(tau)
        radial = np.array([0.0, np.cos(ps), np.sin(ps)])
        ahead = sign * np.array([0.0, -np.sin(ps), np.cos(ps)])
        axis = np.array([1.0, 0.0, 0.0])
        look = radial + np.tan(np.radians(40.0) + lean(tau)) * ahead + np.tan(sway(tau)) * axis
        e = eye(np.array(tau))
        c2w = look_at(e, e + look, axis)
        poses.append(_roll(c2w, roll_wave(tau)))
    return np.stack(poses)
