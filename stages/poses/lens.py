"""The poses stage's lens: how much of the field of view it reaches, where an estimated one was
fitted, and the re-fit of one that bends back inside the field of view as a fisheye.

Why the re-fit: COLMAP self-calibrates SIMPLE_RADIAL, r_d = r (1 + k r^2). Through a wide scope
the fit takes k < 0, and that polynomial stops growing before the edge of the image: the outer
pixels get no ray (C3VD: 5.2% of the octagon) and the angles before the fold come out too
narrow (the bench colon through a 140-degree fisheye: 46.9 degrees at 170 px from the centre,
57.3 true; the tube then fits its SfM points worse than a closed cavity does). The
one-parameter FOV lens (Devernay and Faugeras: r_d = atan(2 r tan(w / 2)) / w) has a fisheye's
shape and never folds. Started from the estimated lens and bundle-adjusted on the same tracks,
it keeps their reprojection error and puts that angle at 54.4 degrees. endopipe's `Camera`
speaks OpenCV's fisheye, so the FOV lens is written as the k1..k4 that match it over the whole
image, and the model is adjusted once more with that lens fixed.

`LensRefit` is what the poses summary records of a re-fit; its `said` is the one sentence the
log and the report show. pycolmap and scipy are imported only by the re-fit itself: the views
and summaries that import this module stay light.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from pydantic import BaseModel, ConfigDict

from endopipe.stages.camera import Camera, lens_valid_mask
from endopipe.stages.io.colmap_model import camera_from_pycolmap

if TYPE_CHECKING:
    import pycolmap

    from endopipe.stages.ingest.view import IngestView

#: Angles the FOV lens is first fitted over (degrees from the optical axis, within the tracks).
START_DEG = (0.5, 45.0)
#: Fewer angles than this before the estimate bends back: too little lens to start from.
MIN_START_ANGLES = 10
#: The OpenCV fisheye must match the FOV lens this well (px) over the image, else no refit.
MATCH_PX = 0.05


# --- how far the lens reaches, where it was fitted ----------------------------------------------
def lens_reach(k: Camera, ingest: IngestView) -> float | None:
    """The share of the field-of-view mask's pixels that the lens model gives a ray (None
    without a mask)."""
    fov = ingest.fov()
    if fov is None:
        return None
    if (k.width, k.height) != (ingest.width, ingest.height):
        k = k.scaled(ingest.width, ingest.height)
    inside = fov > 127
    if not inside.any() or inside.shape != (k.height, k.width):
        return None
    return round(float((inside & lens_valid_mask(k)).sum()) / float(inside.sum()), 4)


def lens_folds(camera: Camera, ingest: IngestView) -> bool:
    """Whether the lens model leaves some pixel of the field of view (the whole image without a
    mask) without a ray."""
    reach = lens_reach(camera, ingest)
    if reach is None:
        return not bool(lens_valid_mask(camera).all())
    return reach < 1.0


def reach_note(camera_model: str, reach: float | None, estimated: bool) -> str | None:
    """The log line for a lens that gives part of the field of view no ray (None: it reaches
    all of it, or there is no mask to tell)."""
    if reach is None or reach >= 1.0:
        return None
    return (
        f"lens: the {camera_model} model bends back before the edge of the field of view and "
        f"reaches {reach:.1%} of it; the rest gets no ray, so no depth"
        + (
            " (poses.unfold_lens re-fits an estimated lens as a fisheye that reaches every pixel)"
            if estimated
            else ""
        )
    )


def fitted_radius_px(rec: pycolmap.Reconstruction) -> float | None:
    """How far from the principal point (px) the tracked features reach: the 99.9th percentile
    of every observation's distance. A lens estimated from them is fitted within it and
    extrapolated past it. None without observations or with several cameras."""
    if len(rec.cameras) != 1:
        return None
    camera = next(iter(rec.cameras.values()))
    centre = np.array([camera.principal_point_x, camera.principal_point_y])
    xy = [p.xy for image in rec.images.values() for p in image.points2D if p.has_point3D()]
    if not xy:
        return None
    return float(np.percentile(np.linalg.norm(np.asarray(xy) - centre, axis=1), 99.9))


def past_fitted_radius(
    camera: Camera, fitted_radius_px: float | None, fitted_width: int, share: float = 1.0
) -> np.ndarray | None:
    """(H, W) bool for `camera`'s image: the pixels farther from its principal point than `share`
    of the radius an estimated lens was fitted within (given in pixels of an image
    `fitted_width` wide); None when the lens was given."""
    if fitted_radius_px is None:
        return None
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    radius = share * fitted_radius_px * camera.width / fitted_width
    return np.hypot(u - camera.cx, v - camera.cy) > radius


# --- the re-fit as a fisheye --------------------------------------------------------------------
class LensRefit(BaseModel):
    """An estimated lens that bent back inside the field of view, re-fitted as a fisheye: the
    poses summary's `lens_refit`."""

    model_config = ConfigDict(extra="forbid")

    from_model: str  # the COLMAP model estimated, e.g. SIMPLE_RADIAL
    to_model: str  # the COLMAP model written, OPENCV_FISHEYE
    omega: float  # the fitted FOV lens's w (radians)
    focal_px: float  # the fitted FOV lens's focal length (px)
    reprojection_before_px: float  # mean reprojection error of the estimated model
    reprojection_after_px: float  # ... and of the re-fitted one
    widest_deg: float  # the ray angle of the image's farthest pixel from the principal point
    seconds: float  # the re-fit's time

    @property
    def said(self) -> str:
        """The re-fit in words: the log and the report both show this sentence."""
        return (
            f"{self.from_model} bent back inside the field of view: FOV lens (w "
            f"{self.omega:.3f}) written as {self.to_model}, reprojection "
            f"{self.reprojection_before_px:.3f} -> {self.reprojection_after_px:.3f} px, the "
            f"farthest pixel at {self.widest_deg:.1f} deg"
        )


@dataclass
class Refit:
    """The re-fitted model and lens, and the record the summary keeps of them."""

    reconstruction: pycolmap.Reconstruction
    camera: Camera
    record: LensRefit

    @property
    def colmap_model(self) -> str:
        return self.record.to_model


def unfold(
    rec: pycolmap.Reconstruction, refine_principal_point: bool, log: Callable[[str], None]
) -> Refit | None:
    """`rec` with its lens re-fitted as a fisheye, or None (said in the log) when it cannot
    be."""
    refit = refit_as_fisheye(rec, refine_principal_point)
    if refit is None:
        log("lens: bends back inside the field of view and could not be re-fitted as a fisheye")
    else:
        log(f"lens: {refit.record.said}; every pixel has a ray")
    return refit


def refit_as_fisheye(rec: pycolmap.Reconstruction, refine_principal_point: bool) -> Refit | None:
    """A copy of `rec` whose one camera is re-fitted as a FOV lens written as OpenCV's fisheye,
    its poses and points adjusted with it; None when `rec` has several cameras or the fisheye
    cannot hold the FOV lens."""
    import pycolmap

    if len(rec.cameras) != 1:
        return None
    t0 = time.perf_counter()
    cam_id, before = next(iter(rec.cameras.items()))
    start = _fov_like(before)
    if start is None:
        return None
    work = pycolmap.Reconstruction(rec)
    work.cameras[cam_id] = start
    _adjust(work, refine_intrinsics=True, refine_principal_point=refine_principal_point)
    fitted = work.cameras[cam_id]
    omega, focal = float(fitted.params[4]), float(fitted.mean_focal_length())
    fisheye = _as_opencv_fisheye(fitted)
    if fisheye is None:
        return None
    work.cameras[cam_id], widest = fisheye
    _adjust(work, refine_intrinsics=False, refine_principal_point=False)
    camera, model = camera_from_pycolmap(work.cameras[cam_id])
    record = LensRefit(
        from_model=camera_from_pycolmap(before)[1],
        to_model=model,
        omega=omega,
        focal_px=focal,
        reprojection_before_px=float(rec.compute_mean_reprojection_error()),
        reprojection_after_px=float(work.compute_mean_reprojection_error()),
        widest_deg=widest,
        seconds=round(time.perf_counter() - t0, 2),
    )
    return Refit(reconstruction=work, camera=camera, record=record)


def _fov_like(camera: pycolmap.Camera) -> pycolmap.Camera | None:
    """A FOV camera that matches `camera` along a radius out to START_DEG[1] or to where its
    lens bends back, whichever is nearer (where features are tracked), its principal point
    kept; None when it bends back within a few degrees."""
    import pycolmap
    from scipy.optimize import least_squares

    theta = np.radians(np.linspace(*START_DEG, 90))
    rays = np.stack([np.tan(theta), np.zeros_like(theta), np.ones_like(theta)], 1)
    target = camera.img_from_cam(rays)[:, 0]
    grows = np.concatenate([[True], np.diff(target) > 0])
    upto = int(np.argmin(grows)) if not grows.all() else len(target)  # before any fold
    if upto < MIN_START_ANGLES:
        return None
    rays, target = rays[:upto], target[:upto]
    f = float(camera.mean_focal_length())
    cx, cy = camera.principal_point_x, camera.principal_point_y

    def make(focal: float, omega: float) -> pycolmap.Camera:
        return pycolmap.Camera(
            model="FOV",
            width=camera.width,
            height=camera.height,
            params=[focal, focal, cx, cy, omega],
        )

    def residual(q: np.ndarray) -> np.ndarray:
        return np.nan_to_num(make(*q).img_from_cam(rays)[:, 0] - target, nan=1e3)

    q = least_squares(residual, [f, 1.0], bounds=([1e-3, 1e-3], [np.inf, 3.0])).x
    out = make(*q)
    out.camera_id = camera.camera_id
    return out


def _as_opencv_fisheye(camera: pycolmap.Camera) -> tuple[pycolmap.Camera, float] | None:
    """OpenCV's fisheye (k1..k4) matching `camera` out to the image's farthest pixel, with
    that pixel's ray angle (degrees); None when no fit is within MATCH_PX."""
    import pycolmap
    from scipy.optimize import least_squares

    cx, cy = camera.principal_point_x, camera.principal_point_y
    far = np.hypot(max(cx, camera.width - cx), max(cy, camera.height - cy)) + 1.0
    radius = np.linspace(1.0, far, 300)
    fx, fy = camera.focal_length_x, camera.focal_length_y
    # along x, in units of fx (the FOV model's two focal lengths scale the axes alike)
    rays = camera.cam_from_img(np.stack([cx + radius, np.full_like(radius, cy)], 1))
    theta = np.arctan(np.abs(rays[:, 0]))
    if not np.isfinite(theta).all() or np.any(np.diff(theta) <= 0):
        return None

    def residual(p: np.ndarray) -> np.ndarray:
        t2 = theta * theta
        poly = 1 + t2 * (p[1] + t2 * (p[2] + t2 * (p[3] + t2 * p[4])))
        return p[0] * theta * poly - radius

    p = least_squares(residual, [fx, 0.0, 0.0, 0.0, 0.0]).x
    if np.abs(residual(p)).max() > MATCH_PX:
        return None
    out = pycolmap.Camera(
        camera_id=camera.camera_id,
        model="OPENCV_FISHEYE",
        width=camera.width,
        height=camera.height,
        params=[p[0], p[0] * fy / fx, cx, cy, *p[1:]],
    )
    return out, float(np.degrees(theta[-1]))


def _adjust(
    rec: pycolmap.Reconstruction, refine_intrinsics: bool, refine_principal_point: bool
) -> None:
    """One global bundle adjustment of `rec` (its poses and points; the lens when asked), as
    `pycolmap.bundle_adjustment` does it (every registered image, the gauge fixed by two
    cameras) but through the adjuster itself: that wrapper turns COLMAP's logging back on and
    writes its report to stderr beside our lines."""
    import pycolmap

    options = pycolmap.BundleAdjustmentOptions()
    options.print_summary = False
    options.refine_focal_length = refine_intrinsics
    options.refine_extra_params = refine_intrinsics
    options.refine_principal_point = refine_intrinsics and refine_principal_point
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.reg_image_ids():
        config.add_image(image_id)
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    pycolmap.create_default_bundle_adjuster(options, config, rec).solve()
    rec.update_point_3d_errors()
