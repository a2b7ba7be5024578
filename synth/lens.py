"""The synthetic camera's lens and sensor falloff, as the project's `Camera` writes them.

Frames are ray-cast through `image_directions(camera)` (the lens undone per pixel), so the image
is what the lens sees and gt depth, intrinsics.json and every later stage share one convention.

Lenses (principal point at the image centre, square pixels; the focal length is chosen so that
the image's outer corners, at (-0.5, -0.5) and (W - 0.5, H - 0.5), see `fov_diag_deg`):
- pinhole: no distortion;
- barrel: OpenCV radial-tangential, k1 = -0.3, k2 = 0.06 (p1 = p2 = 0), 110 deg diagonal by
  default: the corner sits at 0.64 of its pinhole radius. 9 k1^2 < 20 k2, so d r_d / d r =
  1 + 3 k1 r^2 + 5 k2 r^4 has no real root: the radial map never folds back, at any radius.
  COLMAP's OPENCV model holds it exactly (no k3);
- fisheye: OpenCV equidistant, k1 = -0.05, k2 = 0.01, 140 deg diagonal by default;
- c3vd: C3VD's CF-HQ190L colonoscope, the fisheye fitted to its published omnidirectional
  calibration (c3vd_lens.py), at any 5:4 image size.

Vignetting: linear intensity times 1 - S (r / r_corner)^2, r the distance from the principal
point in pixels, r_corner that of the farthest outer image corner: the corners get 1 - S of the
centre's light. It acts on the sensor, after the sequence's exposure is fixed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from endopipe.stages.camera import Camera, distort_normalised, pixel_grid

LensName = Literal["pinhole", "barrel", "fisheye", "c3vd"]


@dataclass(frozen=True)
class Lens:
    """A lens design: its model and coefficients as `Camera` takes them, and its usual FOV."""

    model: Literal["pinhole", "opencv", "fisheye"]
    dist: tuple[float, ...] | None
    fov_diag_deg: float | None  # None: the pinhole keeps SynthConfig.fov_deg (horizontal)


LENSES: dict[str, Lens] = {
    "pinhole": Lens("pinhole", None, None),
    "barrel": Lens("opencv", (-0.3, 0.06, 0.0, 0.0), 110.0),
    "fisheye": Lens("fisheye", (-0.05, 0.01, 0.0, 0.0), 140.0),
    "c3vd": Lens("fisheye", None, None),  # C3VD's scope: its published calibration (c3vd_lens.py)
}


def _corner_radius_px(width: int, height: int) -> float:
    """Distance from the image centre ((W - 1) / 2, (H - 1) / 2) to an outer image corner."""
    return float(np.hypot(width / 2.0, height / 2.0))


def _radial_profile(lens: Lens, theta: np.ndarray) -> np.ndarray:
    """Distorted normalised radius of rays at angles `theta` (rad) from the optical axis."""
    dist = list(lens.dist) if lens.dist else None
    unit = Camera(width=1, height=1, fx=1.0, fy=1.0, cx=0.0, cy=0.0, model=lens.model, dist=dist)
    xy = np.stack([np.tan(theta), np.zeros_like(theta)], -1)
    return distort_normalised(unit, xy)[..., 0]


def lens_camera(
    width: int, height: int, name: LensName, fov_deg: float, fov_diag_deg: float | None
) -> Camera:
    """The synthetic camera: `fov_diag_deg` (or the lens's default) across the image diagonal;
    a pinhole without either keeps `fov_deg` across the width, the numbers synth always had.
    C3VD's scope is its published calibration, whatever the field of view asked."""
    if name == "c3vd":
        from endopipe.synth.c3vd_lens import c3vd_camera

        return c3vd_camera(width, height)
    lens = LENSES[name]
    diag = fov_diag_deg if fov_diag_deg is not None else lens.fov_diag_deg
    if diag is None:
        fx = 0.5 * width / np.tan(np.radians(fov_deg) / 2.0)
    else:
        r_d = float(_radial_profile(lens, np.array([np.radians(diag) / 2.0]))[0])
        fx = _corner_radius_px(width, height) / r_d
    camera = Camera(
        width=width,
        height=height,
        fx=fx,
        fy=fx,
        cx=(width - 1) / 2.0,
        cy=(height - 1) / 2.0,
        model=lens.model,
        dist=list(lens.dist) if lens.dist else None,
    )
    if diag is not None:
        check_monotonic(lens, np.radians(diag) / 2.0)
    return camera


def check_monotonic(lens: Lens, theta_max: float, samples: int = 20_000) -> None:
    """Raise if the lens's radial map folds back before `theta_max` (the corner ray's angle):
    a fold-back would show two directions at one pixel. Checked on a dense sampling of the
    angle, which is exact for these radial lenses (no tangential terms)."""
    theta = np.linspace(0.0, theta_max, samples)
    r_d = _radial_profile(lens, theta)
    if not np.all(np.diff(r_d) > 0):
        bad = np.degrees(theta[1:][np.diff(r_d) <= 0][0])
        raise ValueError(f"lens {lens.model} {lens.dist} folds back at {bad:.1f} deg off-axis")


def vignetting_gain(camera: Camera, strength: float) -> np.ndarray | None:
    """(H, W) linear gain 1 - strength (r / r_corner)^2, or None for strength 0."""
    if strength == 0:
        return None
    u, v = pixel_grid(camera.width, camera.height)
    corners_u = np.array([-0.5, camera.width - 0.5])
    corners_v = np.array([-0.5, camera.height - 0.5])
    r_corner2 = np.max(
        (corners_u[:, None] - camera.cx) ** 2 + (corners_v[None, :] - camera.cy) ** 2
    )
    r2 = (u - camera.cx) ** 2 + (v - camera.cy) ** 2
    return 1.0 - strength * r2 / r_corner2
