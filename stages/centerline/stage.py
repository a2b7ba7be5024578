"""centerline: the lumen's centre curve and radius from the camera path and the sparse points.

Seed §3.3: the anatomical prior is "a generalized tube model that follows the approximate path of
the camera". This stage estimates it once, so the NeRF stage can use it as a signed-distance
proxy (stages/prior.py):

1. A smoothing spline through the registered camera centres (smoothing scaled to the wobble of
   the path about a local-linear fit one radius wide), extended a little ahead of the cameras
   (along their viewing direction) and a little behind; a line when there are few cameras.
2. The curve is moved towards the true axis: in slices along it, a robust circle fitted to the
   sparse points in the normal plane gives the axis offset (used where the points go round the
   lumen); the offsets are smoothed along the curve.
3. The radius along the curve: in slices, the distance of the points to the curve, MAD outlier
   rejection, angle-balanced median, smoothed along the curve (sparse SfM points lie on the
   visible wall only, so that is a fair radius estimate). Fallbacks: a global median, then a
   default from the camera path, noted in the summary.

`prior: cavity` fits an ellipsoid to the points instead (robust algebraic fit, refined by
robust least squares on the point-to-ellipsoid distance).

The estimation is plain functions over arrays (`fit_tube`, `fit_cavity`, `compare_to_truth`), so
it is testable without the pipeline.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field

from endopipe.pipeline.errors import StageFailed
from endopipe.pipeline.stage import Stage, StageConfig, StageContext, Summary, write_json
from endopipe.stages.centerline.prior import EllipsoidPrior, LumenPrior, TubePrior
from endopipe.stages.poses.view import PosesView

MAD_TO_SIGMA = 1.4826


class CenterlineConfig(StageConfig):
    prior: Literal["tube", "cavity"] = Field(
        "tube", description="tube: a curve with a radius (colon); cavity: an ellipsoid (stomach)."
    )
    n_samples: int = Field(256, ge=16, le=4096, description="Samples of the output curve.")
    smoothing: float = Field(
        1.0,
        ge=0,
        description="Spline smoothing s = smoothing x n x wobble^2 (wobble: the path's scatter "
        "about a local-linear fit one radius wide). 0 interpolates the cameras.",
    )
    smooth_radii: float = Field(
        1.0, gt=0, description="Width of the local-linear fit that measures the wobble, in radii."
    )
    extend_ahead: float = Field(
        1.0, ge=0, description="Extend the curve past the cameras it looks towards, in radii."
    )
    extend_behind: float = Field(
        0.5, ge=0, description="Extend the curve past the cameras it looks away from, in radii."
    )
    min_cameras: int = Field(
        5, ge=2, description="Fewer registered cameras than this: a line (PCA axis), no spline."
    )
    recentre: bool = Field(
        True, description="Move the curve onto the axis of circles fitted to the points."
    )
    recentre_iters: int = Field(2, ge=0, le=10, description="Rounds of recentring.")
    max_shift: float = Field(
        0.5, ge=0, description="Largest recentring offset accepted for a slice, in radii."
    )
    min_sectors: int = Field(
        6,
        ge=3,
        le=8,
        description="A slice's circle counts when its points fill this many of "
        "8 angular sectors around the curve.",
    )
    recentre_bin_width: float = Field(
        0.5, gt=0, description="Slice width of the circle fits, along the curve, in radii."
    )
    recentre_smoothing: float = Field(
        1.0, gt=0, description="Gaussian smoothing of the recentring offsets, in radii."
    )
    bin_width: float = Field(
        0.2, gt=0, description="Slice width of the radius estimate, along the curve, in radii."
    )
    radius_smoothing: float = Field(
        0.25, gt=0, description="Gaussian smoothing of the radius along the curve, in radii."
    )
    min_points_per_bin: int = Field(12, ge=3, description="Points a slice needs to count.")
    min_points: int = Field(
        30, ge=3, description="Fewer usable points: no radius profile (global median fallback)."
    )
    outlier_mad: float = Field(3.0, gt=0, description="Outlier rejection at this many MADs.")
    max_points: int = Field(
        200_000, ge=1000, description="Subsample the sparse points to at most this many."
    )
    default_radius_mm: float = Field(
        15.0, gt=0, description="Radius when no points are usable and cameras are metric (mm)."
    )
    default_radius_fraction: float = Field(
        0.1,
        gt=0,
        description="Radius when no points are usable and cameras are not metric, as a fraction "
        "of the camera path length.",
    )
    far_radii: float = Field(
        6.0, gt=0, description="The prior's default cap for ray far bounds, in radii."
    )


class CenterlineSummary(Summary):
    kind: str
    length: float
    mean_radius: float
    radius_source: str
    radius_note: str
    n_points_used: int
    n_cameras: int
    units: str
    recentred_slices: int = 0
    centerline_mean_dist: float | None = None
    centerline_mean_dist_pct_of_radius: float | None = None
    radius_error_pct: float | None = None


@dataclass
class CenterlineFit:
    """A fitted lumen: curve samples (uniform in arc length) with a radius each."""

    kind: str
    points: np.ndarray  # (M, 3)
    radius: np.ndarray  # (M,)
    arclength: np.ndarray  # (M,)
    radius_source: str  # "points" | "fallback"
    radius_note: str
    n_points_used: int
    camera_span: tuple[float, float]  # arc length range the cameras project to
    recentred_slices: int = 0
    bins: tuple[np.ndarray, np.ndarray] = field(
        default_factory=lambda: (np.zeros(0), np.zeros(0))
    )  # raw per-slice radius (arc length, radius), for plots
    ellipsoid: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # centre, axes, rotation
    notes: list[str] = field(default_factory=list)

    @property
    def length(self) -> float:
        return float(self.arclength[-1]) if len(self.arclength) else 0.0

    def prior(self, far_radii: float = 6.0) -> LumenPrior:
        if self.ellipsoid is not None:
            return EllipsoidPrior(*self.ellipsoid, far_radii=far_radii)
        return TubePrior(self.points, self.radius, open_ends=True, far_radii=far_radii)

    def to_json(self, units: str) -> dict:
        data = {
            "kind": self.kind,
            "units": units,
            "points": np.round(self.points, 6).tolist(),
            "radius": np.round(self.radius, 6).tolist(),
            "arclength": np.round(self.arclength, 6).tolist(),
            "camera_span": [round(self.camera_span[0], 6), round(self.camera_span[1], 6)],
            "radius_source": self.radius_source,
        }
        if self.ellipsoid is not None:
            c, a, r = self.ellipsoid
            data["ellipsoid"] = {"centre": c.tolist(), "axes": a.tolist(), "rotation": r.tolist()}
        return data


# --- small robust helpers ---------------------------------------------------------------------
def robust_inliers(values: np.ndarray, k: float) -> np.ndarray:
    """Mask of values within k MADs (as sigma) of the median."""
    if len(values) == 0:
        return np.zeros(0, dtype=bool)
    med = np.median(values)
    mad = MAD_TO_SIGMA * np.median(np.abs(values - med))
    if mad <= 1e-12 * max(abs(med), 1.0):
        return np.ones(len(values), dtype=bool)
    return np.abs(values - med) <= k * mad


def gaussian_fill(
    x_out: np.ndarray, x: np.ndarray, y: np.ndarray, sigma: float, prior: np.ndarray | float
) -> np.ndarray:
    """Normalised Gaussian smoothing of samples (x, y) at x_out; pulled to `prior` where data
    are absent (a weight of 1e-3 of one sample at the centre)."""
    y = np.asarray(y, dtype=np.float64)
    prior = np.broadcast_to(np.asarray(prior, np.float64), (len(x_out), *y.shape[1:]))
    if len(x) == 0:
        return prior.copy()
    w = np.exp(-0.5 * ((x_out[:, None] - x[None, :]) / sigma) ** 2)  # (M, K)
    eps = 1e-3
    num = w @ y.reshape(len(x), -1) + eps * prior.reshape(len(x_out), -1)
    den = w.sum(1, keepdims=True) + eps
    return (num / den).reshape(prior.shape)


def resample_polyline(pts: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """n points uniform in arc length along a polyline, and their arc lengths."""
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0:
        return np.repeat(pts[:1], n, axis=0), np.zeros(n)
    s_new = np.linspace(0.0, s[-1], n)
    out = np.stack([np.interp(s_new, s, pts[:, k]) for k in range(3)], 1)
    return out, s_new


def _dedupe(pts: np.ndarray, tol: float) -> np.ndarray:
    keep = [0]
    for i in range(1, len(pts)):
        if np.linalg.norm(pts[i] - pts[keep[-1]]) > tol:
            keep.append(i)
    return np.asarray(keep)


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v)
    return v / n if n > 1e-12 else v


# --- the camera path ------------------------------------------------------------------------
def local_linear(s: np.ndarray, y: np.ndarray, s_out: np.ndarray, bandwidth: float) -> np.ndarray:
    """Gaussian-weighted local-linear regression of y (N, D) on s, evaluated at s_out."""
    w = np.exp(-0.5 * ((s_out[:, None] - s[None, :]) / bandwidth) ** 2)  # (M, N)
    out = np.empty((len(s_out), y.shape[1]))
    for i in range(len(s_out)):
        wi = w[i]
        sw = wi.sum()
        if sw <= 1e-12:
            out[i] = y[np.argmin(np.abs(s - s_out[i]))]
            continue
        m = (wi @ s) / sw
        ds = s - m
        var = wi @ (ds * ds)
        ym = (wi @ y) / sw
        slope = ((wi * ds) @ y) / var if var > 1e-12 else 0.0
        out[i] = ym + slope * (s_out[i] - m)
    return out


def smooth_camera_path(
    centres: np.ndarray, radius: float, cfg: CenterlineConfig, notes: list[str]
) -> np.ndarray:
    """Dense samples (K, 3) of a smooth curve through the camera centres, in frame order."""
    scale = max(float(np.ptp(centres, axis=0).max()) if len(centres) else 0.0, 1e-9)
    keep = _dedupe(centres, 1e-6 * scale)
    c = centres[keep]
    n = len(c)
    chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(c, axis=0), axis=1))])
    if n < cfg.min_cameras or chord[-1] <= 0:
        notes.append(f"{n} distinct camera centre(s): line fit")
        return _line_through(c)
    bandwidth = cfg.smooth_radii * radius
    trend = local_linear(chord, c, chord, bandwidth)
    wobble2 = float(np.mean(np.sum((c - trend) ** 2, axis=1)))
    try:
        from scipy.interpolate import splev, splprep

        k = min(3, n - 1)
        tck, _ = splprep(c.T, u=chord / chord[-1], k=k, s=cfg.smoothing * n * wobble2)
        dense = np.stack(splev(np.linspace(0.0, 1.0, 2000), tck), 1)
    except Exception as err:  # noqa: BLE001 - any spline failure falls back to the trend
        notes.append(f"spline failed ({err}); local-linear path")
        dense = local_linear(chord, c, np.linspace(0.0, chord[-1], 500), bandwidth)
    return dense


def _line_through(c: np.ndarray) -> np.ndarray:
    """A segment along the principal axis of the points, spanning their projections."""
    mean = c.mean(0)
    if len(c) < 2:
        return np.stack([mean, mean])
    _, _, vt = np.linalg.svd(c - mean, full_matrices=False)
    axis = vt[0]
    if np.dot(c[-1] - c[0], axis) < 0:
        axis = -axis
    proj = (c - mean) @ axis
    return mean + np.linspace(proj.min(), proj.max(), 50)[:, None] * axis


def extend_ends(
    dense: np.ndarray,
    view_dirs: np.ndarray,
    radius: float,
    cfg: CenterlineConfig,
    notes: list[str],
) -> np.ndarray:
    """Extend the curve straight past both ends: `extend_ahead` radii at an end the cameras
    there look out of (blending their mean viewing direction with the tangent), otherwise
    `extend_behind` radii along the tangent."""
    k = max(1, min(10, len(view_dirs) // 4 if len(view_dirs) >= 8 else len(view_dirs)))
    seg = np.linalg.norm(np.diff(dense, axis=0), axis=1)
    length = float(seg.sum())
    step = max(length / max(len(dense) - 1, 1), radius / 20.0, 1e-9)
    mean_view = _unit(view_dirs.mean(0)) if len(view_dirs) else np.zeros(3)
    if length <= 1e-9:
        # A single point: the axis is the viewing direction.
        axis = mean_view if np.linalg.norm(mean_view) > 0 else np.array([0.0, 0.0, 1.0])
        dense = np.stack([dense[0] - 1e-3 * radius * axis, dense[0] + 1e-3 * radius * axis])
    parts = [dense]
    for end in ("start", "end"):
        if end == "end":
            p, tangent = dense[-1], _unit(dense[-1] - dense[max(0, len(dense) - 6)])
            view = _unit(view_dirs[-k:].mean(0)) if len(view_dirs) else np.zeros(3)
        else:
            p, tangent = dense[0], _unit(dense[0] - dense[min(len(dense) - 1, 5)])
            view = _unit(view_dirs[:k].mean(0)) if len(view_dirs) else np.zeros(3)
        if np.linalg.norm(tangent) < 1e-12:
            tangent = mean_view if end == "end" else -mean_view
        looks_out = float(np.dot(view, tangent)) > 0.2
        if looks_out:
            direction, dist = _unit(tangent + view), cfg.extend_ahead * radius
        else:
            direction, dist = tangent, cfg.extend_behind * radius
        n = int(np.ceil(dist / step))
        if n == 0:
            continue
        ext = p + np.linspace(dist / n, dist, n)[:, None] * direction
        parts = parts + [ext] if end == "end" else [ext[::-1]] + parts
    return np.concatenate(parts)


# --- points against the curve -----------------------------------------------------------------
def _normal_frame(tangent: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([1.0, 0.0, 0.0]) if abs(tangent[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    n1 = _unit(np.cross(tangent, helper))
    return n1, np.cross(tangent, n1)


def fit_circle(xy: np.ndarray, iters: int = 6) -> tuple[np.ndarray, float] | None:
    """Robust 2-D circle: algebraic (Kasa) fit, then Huber-weighted Gauss-Newton."""
    if len(xy) < 3:
        return None
    a = np.column_stack([xy, np.ones(len(xy))])
    b = (xy**2).sum(1)
    try:
        sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    except np.linalg.LinAlgError:
        return None
    centre = sol[:2] / 2.0
    r2 = sol[2] + centre @ centre
    if r2 <= 0:
        return None
    r = float(np.sqrt(r2))
    for _ in range(iters):
        diff = xy - centre
        dist = np.linalg.norm(diff, axis=1).clip(1e-12)
        res = dist - r
        scale = MAD_TO_SIGMA * np.median(np.abs(res)) + 1e-9 * r
        w = np.minimum(1.0, 1.5 * scale / np.maximum(np.abs(res), 1e-12))
        jac = np.column_stack([-diff / dist[:, None], -np.ones(len(xy))])
        jw = jac * w[:, None]
        try:
            delta = np.linalg.solve(jw.T @ jac + 1e-9 * np.eye(3), -(jw.T @ res))
        except np.linalg.LinAlgError:
            break
        centre, r = centre + delta[:2], r + float(delta[2])
        if np.linalg.norm(delta) < 1e-6 * abs(r):
            break
    if not np.isfinite(r) or r <= 0:
        return None
    return centre, r


def _sectors(angles: np.ndarray) -> np.ndarray:
    return np.floor((angles + np.pi) / (np.pi / 4)).astype(int).clip(0, 7)


@dataclass
class _Slices:
    s: np.ndarray  # slice centres (arc length)
    edges: np.ndarray
    which: np.ndarray  # slice index of each point (-1: none)


def _slices(length: float, width: float, s_points: np.ndarray) -> _Slices:
    n = max(1, int(np.ceil(length / width)))
    edges = np.linspace(0.0, length, n + 1)
    which = np.searchsorted(edges, s_points, side="right") - 1
    which[(s_points < 0) | (s_points > length)] = -1
    which = np.minimum(which, n - 1)
    return _Slices(0.5 * (edges[:-1] + edges[1:]), edges, which)


def recentre_curve(
    curve: np.ndarray,
    points: np.ndarray,
    radius: float,
    cfg: CenterlineConfig,
) -> tuple[np.ndarray, int]:
    """Move curve samples onto the axis of robust circles fitted to the points, slice by slice.
    Returns the new curve (resampled uniformly) and the number of slices that contributed."""
    curve, s_curve = resample_polyline(curve, len(curve))
    tube = TubePrior(curve, radius, open_ends=True, grid=False)
    c = tube.closest(points)
    s_p = c["s"].numpy().astype(np.float64)
    off = points - c["foot"].numpy()  # perpendicular offsets from the curve
    d = np.linalg.norm(off, axis=1)
    usable = (d > 0.25 * radius) & (d < 2.5 * radius)
    usable[usable] = robust_inliers(d[usable], cfg.outlier_mad)
    sl = _slices(tube.length, cfg.recentre_bin_width * radius, s_p)
    centres_s, shifts = [], []
    tangents = np.gradient(curve, axis=0)
    for b, s_mid in enumerate(sl.s):
        sel = usable & (sl.which == b)
        if sel.sum() < cfg.min_points_per_bin:
            continue
        i = int(np.clip(np.searchsorted(s_curve, s_mid), 0, len(curve) - 1))
        n1, n2 = _normal_frame(_unit(tangents[i]))
        xy = np.column_stack([off[sel] @ n1, off[sel] @ n2])
        fit = fit_circle(xy)
        if fit is None:
            continue
        centre, r = fit
        if np.linalg.norm(centre) > cfg.max_shift * radius or not (0.3 * radius < r < 3 * radius):
            continue
        rel = xy - centre
        covered = len(np.unique(_sectors(np.arctan2(rel[:, 1], rel[:, 0]))))
        if covered < cfg.min_sectors:
            continue
        centres_s.append(s_mid)
        shifts.append(centre[0] * n1 + centre[1] * n2)
    if not shifts:
        return curve, 0
    shift = gaussian_fill(
        s_curve, np.array(centres_s), np.array(shifts), cfg.recentre_smoothing * radius, 0.0
    )
    # Remove the along-curve component so samples do not bunch up.
    t_unit = tangents / np.linalg.norm(tangents, axis=1, keepdims=True).clip(1e-12)
    shift -= np.sum(shift * t_unit, axis=1, keepdims=True) * t_unit
    new, _ = resample_polyline(curve + shift, len(curve))
    return new, len(shifts)


def radius_profile(
    curve: np.ndarray,
    points: np.ndarray,
    radius_guess: float,
    cfg: CenterlineConfig,
) -> tuple[np.ndarray | None, float | None, int, tuple[np.ndarray, np.ndarray]]:
    """Radius per curve sample from the points' distances to the curve.

    Returns (profile or None, global median or None, points used, (slice s, slice radius)).
    """
    tube = TubePrior(curve, radius_guess, open_ends=True, grid=False)
    c = tube.closest(points)
    s_p = c["s"].numpy().astype(np.float64)
    d = c["dist"].numpy().astype(np.float64)
    off = points - c["foot"].numpy()
    within = (s_p >= 0) & (s_p <= tube.length)
    d_in = d[within]
    if len(d_in) < 3:
        return None, None, 0, (np.zeros(0), np.zeros(0))
    ok = np.zeros(len(d), dtype=bool)
    ok[within] = robust_inliers(d_in, cfg.outlier_mad) & (d_in > 0)
    global_med = float(np.median(d[ok])) if ok.any() else None
    sl = _slices(tube.length, cfg.bin_width * (global_med or radius_guess), s_p)
    s_bins, r_bins, used = [], [], 0
    tangents = np.gradient(tube.points, axis=0)
    for b, s_mid in enumerate(sl.s):
        sel = np.nonzero(ok & (sl.which == b))[0]
        if len(sel) < cfg.min_points_per_bin:
            continue
        db = d[sel]
        inl = robust_inliers(db, cfg.outlier_mad)
        sel, db = sel[inl], db[inl]
        if len(sel) < cfg.min_points_per_bin:
            continue
        # Angle-balanced: the mean of per-sector medians (points crowd on the near wall).
        i = int(np.clip(np.searchsorted(tube.arclength, s_mid), 0, len(tube.points) - 1))
        n1, n2 = _normal_frame(_unit(tangents[i]))
        sec = _sectors(np.arctan2(off[sel] @ n2, off[sel] @ n1))
        meds = [np.median(db[sec == k]) for k in range(8) if (sec == k).sum() >= 2]
        r_b = float(np.mean(meds)) if len(meds) >= 4 else float(np.median(db))
        s_bins.append(s_mid)
        r_bins.append(r_b)
        used += len(sel)
    s_bins_a, r_bins_a = np.array(s_bins), np.array(r_bins)
    if used < cfg.min_points or not s_bins:
        return None, global_med, int(ok.sum()), (s_bins_a, r_bins_a)
    prior = float(np.median(r_bins_a))
    sigma = cfg.radius_smoothing * prior
    profile = gaussian_fill(tube.arclength, s_bins_a, r_bins_a, sigma, prior)
    return profile, global_med, used, (s_bins_a, r_bins_a)


def _rough_radius(centres: np.ndarray, points: np.ndarray, cfg: CenterlineConfig) -> float | None:
    """Median distance of the points to the camera polyline (a first radius scale)."""
    if len(points) < 3:
        return None
    keep = _dedupe(centres, 1e-9 * max(float(np.ptp(centres, axis=0).max()), 1e-9))
    c = centres[keep]
    if len(c) >= 2:
        d = TubePrior(c, 1.0, open_ends=True, grid=False).distance_to_curve(points).numpy()
    else:
        d = np.linalg.norm(points - c[0], axis=1)
    d = d[robust_inliers(d, cfg.outlier_mad) & (d > 0)]
    return float(np.median(d)) if len(d) >= 3 else None


def default_radius(centres: np.ndarray, metric: bool, cfg: CenterlineConfig) -> float:
    if metric:
        return cfg.default_radius_mm
    length = float(np.linalg.norm(np.diff(centres, axis=0), axis=1).sum()) if len(centres) else 0
    return cfg.default_radius_fraction * length if length > 0 else 1.0


def _subsample(points: np.ndarray, n: int) -> np.ndarray:
    if len(points) <= n:
        return points
    idx = np.random.default_rng(0).choice(len(points), n, replace=False)
    return points[np.sort(idx)]


def fit_tube(
    centres: np.ndarray,
    view_dirs: np.ndarray,
    points: np.ndarray,
    cfg: CenterlineConfig | None = None,
    *,
    metric: bool = False,
) -> CenterlineFit:
    """The lumen as a tube: centres (N,3) and viewing directions (N,3) of the registered
    cameras in frame order, sparse wall points (P,3), all in one world frame."""
    cfg = cfg or CenterlineConfig()
    centres = np.asarray(centres, np.float64).reshape(-1, 3)
    view_dirs = np.asarray(view_dirs, np.float64).reshape(-1, 3)
    points = _subsample(np.asarray(points, np.float64).reshape(-1, 3), cfg.max_points)
    points = points[np.isfinite(points).all(1)]
    if len(centres) == 0:
        raise ValueError("no camera centres")
    notes: list[str] = []
    r0 = _rough_radius(centres, points, cfg)
    r_default = default_radius(centres, metric, cfg)
    if r0 is None:
        notes.append("no usable points for a first radius")
    r_scale = r0 if r0 is not None else r_default

    dense = smooth_camera_path(centres, r_scale, cfg, notes)
    dense = extend_ends(dense, view_dirs, r_scale, cfg, notes)
    curve, _ = resample_polyline(dense, cfg.n_samples)
    recentred = 0
    if cfg.recentre and len(points) >= cfg.min_points:
        for _ in range(cfg.recentre_iters):
            curve, n = recentre_curve(curve, points, r_scale, cfg)
            recentred = max(recentred, n)
            if n == 0:
                break
    curve, arclength = resample_polyline(curve, cfg.n_samples)

    profile, global_med, used, bins = radius_profile(curve, points, r_scale, cfg)
    if profile is not None:
        radius, source, note = profile, "points", f"profile from {used} points"
    elif global_med is not None and used >= 3:
        radius = np.full(len(curve), global_med)
        source, note = "fallback", f"global median of {used} points (too few for a profile)"
    else:
        radius = np.full(len(curve), r_default)
        what = f"{cfg.default_radius_mm:g} mm" if metric else "fraction of the camera path"
        source, note = "fallback", f"default radius ({what}): no usable points"
        used = 0
    radius = np.maximum(radius, 1e-6)
    s_cams = TubePrior(curve, radius, grid=False).nearest_param(centres).numpy()
    span = (
        float(np.clip(s_cams.min(), 0, arclength[-1])),
        float(np.clip(s_cams.max(), 0, arclength[-1])),
    )
    return CenterlineFit(
        kind="tube",
        points=curve,
        radius=radius,
        arclength=arclength,
        radius_source=source,
        radius_note=note,
        n_points_used=int(used),
        camera_span=span,
        recentred_slices=recentred,
        bins=bins,
        notes=notes,
    )


# --- cavity -----------------------------------------------------------------------------------
def _ellipsoid_from_quadric(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(centre, axes, rotation) of Ax^2+By^2+Cz^2+2Dxy+2Exz+2Fyz+2Gx+2Hy+2Iz = 1, if it is one."""
    a, b, c, d, e, f, g, h, i = q
    m = np.array([[a, d, e], [d, b, f], [e, f, c]])
    v = np.array([g, h, i])
    try:
        centre = -np.linalg.solve(m, v)
    except np.linalg.LinAlgError:
        return None
    k = 1.0 + centre @ m @ centre
    evals, evecs = np.linalg.eigh(m / k)
    if k <= 0 or np.any(evals <= 0):
        return None
    return centre, 1.0 / np.sqrt(evals), evecs


def inlier_points(points: np.ndarray, outlier_mad: float) -> np.ndarray:
    """Points whose distance to the points' median is not a robust outlier (stray triangulations
    far outside a cavity)."""
    p = np.asarray(points, np.float64)
    return p[robust_inliers(np.linalg.norm(p - np.median(p, axis=0), axis=1), outlier_mad)]


def fit_ellipsoid(
    points: np.ndarray, centres: np.ndarray | None = None, outlier_mad: float = 3.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust ellipsoid through wall points: algebraic fit, then soft-L1 least squares on the
    signed distance (centre, log semi-axes, rotation vector). PCA-scaled fallback."""
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    p = inlier_points(points, outlier_mad)
    mu = p.mean(0)
    scale = float(np.sqrt(((p - mu) ** 2).sum(1).mean())) or 1.0
    x = (p - mu) / scale
    design = np.column_stack(
        [x[:, 0] ** 2, x[:, 1] ** 2, x[:, 2] ** 2, 2 * x[:, 0] * x[:, 1], 2 * x[:, 0] * x[:, 2],
         2 * x[:, 1] * x[:, 2], 2 * x[:, 0], 2 * x[:, 1], 2 * x[:, 2]]
    )  # fmt: skip
    init = None
    if len(p) >= 9:
        q, *_ = np.linalg.lstsq(design, np.ones(len(x)), rcond=None)
        init = _ellipsoid_from_quadric(q)
    if init is None:
        evals, evecs = np.linalg.eigh(np.cov(x.T))
        init = (np.zeros(3), np.sqrt(3.0 * np.maximum(evals, 1e-6)), evecs)
    c0, a0, r0 = init
    if np.linalg.det(r0) < 0:
        r0 = r0.copy()
        r0[:, 2] *= -1
    params0 = np.concatenate([c0, np.log(a0), Rotation.from_matrix(r0).as_rotvec()])

    def residual(params: np.ndarray) -> np.ndarray:
        c, a = params[:3], np.exp(params[3:6])
        rot = Rotation.from_rotvec(params[6:9]).as_matrix()
        y = (x - c) @ rot
        k0 = np.linalg.norm(y / a, axis=1)
        k1 = np.linalg.norm(y / (a * a), axis=1).clip(1e-9)
        return k0 * (k0 - 1.0) / k1  # signed distance, first order (exact for a sphere)

    fit = least_squares(residual, params0, loss="soft_l1", f_scale=0.05, max_nfev=200)
    c, a = fit.x[:3], np.exp(fit.x[3:6])
    rot = Rotation.from_rotvec(fit.x[6:9]).as_matrix()
    return mu + scale * c, scale * a, rot


def moment_ellipsoid(
    points: np.ndarray, outlier_mad: float = 3.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ellipsoid from the second moments of wall points: for points spread over an ellipsoid's
    surface, each semi-axis is sqrt(3 x variance) along it. Cruder than `fit_ellipsoid` but it
    cannot run away."""
    p = inlier_points(points, outlier_mad)
    centre = p.mean(0)
    evals, evecs = np.linalg.eigh(np.cov((p - centre).T))
    order = np.argsort(evals)[::-1]
    rot = evecs[:, order]
    if np.linalg.det(rot) < 0:
        rot[:, 2] *= -1
    return centre, np.sqrt(3.0 * np.maximum(evals[order], 1e-12)), rot


def implausible_ellipsoid(
    centre: np.ndarray,
    axes: np.ndarray,
    rot: np.ndarray,
    cameras: np.ndarray,
    points: np.ndarray,
    max_axis_ratio: float = 2.0,
    min_inside: float = 0.9,
) -> str | None:
    """Why a fitted cavity ellipsoid cannot be right, or None: a semi-axis longer than
    `max_axis_ratio` x the points' extent, or cameras outside it (they are in the cavity)."""
    d = np.linalg.norm(points - np.median(points, axis=0), axis=1)
    extent = float(np.percentile(d, 95)) if len(d) else 0.0
    if extent > 0 and float(np.max(axes)) > max_axis_ratio * extent:
        return f"semi-axis {float(np.max(axes)):.3g} vs point extent {extent:.3g}"
    if len(cameras):
        inside = float(EllipsoidPrior(centre, axes, rot).in_core(cameras, 1.0).numpy().mean())
        if inside < min_inside:
            return f"only {100 * inside:.0f}% of the cameras inside"
    return None


def fit_cavity(
    centres: np.ndarray,
    view_dirs: np.ndarray,
    points: np.ndarray,
    cfg: CenterlineConfig | None = None,
    *,
    metric: bool = False,
) -> CenterlineFit:
    """The lumen as an ellipsoid; its "centre line" is the long axis with the section radius."""
    cfg = cfg or CenterlineConfig()
    centres = np.asarray(centres, np.float64).reshape(-1, 3)
    points = _subsample(np.asarray(points, np.float64).reshape(-1, 3), cfg.max_points)
    points = points[np.isfinite(points).all(1)]
    notes: list[str] = []
    if len(points) >= max(cfg.min_points, 9):
        centre, axes, rot = fit_ellipsoid(points, centres, cfg.outlier_mad)
        source, note, used = "points", f"ellipsoid fit to {len(points)} points", len(points)
        problem = implausible_ellipsoid(centre, axes, rot, centres, points)
        if problem:
            # Noisy or one-sided points (e.g. poorly registered frames) can drive the fit to a
            # huge or misplaced ellipsoid: fall back to the points' second moments.
            centre, axes, rot = moment_ellipsoid(points, cfg.outlier_mad)
            # The cameras are in the cavity: grow the axes (at most 2x) until 90% of them are.
            k = np.linalg.norm(((centres - centre) @ rot) / axes, axis=1)
            axes = axes * float(np.clip(np.percentile(k, 90) * 1.05, 1.0, 2.0))
            note = f"moment ellipsoid of {len(points)} points (the fit was rejected: {problem})"
            notes.append(f"ellipsoid fit rejected: {problem}")
    else:
        r = default_radius(centres, metric, cfg)
        centre = centres.mean(0) if len(centres) else np.zeros(3)
        spread = np.sqrt(np.linalg.eigvalsh(np.cov(centres.T))) if len(centres) > 3 else 0
        axes = np.maximum(r, np.sort(2.0 * np.atleast_1d(spread))[::-1] * np.ones(3))
        rot, source, note, used = np.eye(3), "fallback", "default sphere: too few points", 0
    prior = EllipsoidPrior(centre, axes, rot)
    inside = prior.in_core(centres, 1.0).numpy().mean() if len(centres) else 1.0
    if inside < 0.9:
        notes.append(f"only {100 * inside:.0f}% of the cameras are inside the fitted ellipsoid")
    a, rot = prior.axes, prior.rotation
    u = np.linspace(-1.0, 1.0, cfg.n_samples)
    pts = prior.centre + (u * a[0])[:, None] * rot[:, 0]
    radius = np.sqrt(a[1] * a[2]) * np.sqrt(np.clip(1.0 - u * u, 0.0, None))
    s_cams = (centres - prior.centre) @ rot[:, 0] + a[0] if len(centres) else np.zeros(1)
    span = (float(np.clip(s_cams.min(), 0, 2 * a[0])), float(np.clip(s_cams.max(), 0, 2 * a[0])))
    return CenterlineFit(
        kind="cavity",
        points=pts,
        radius=radius,
        arclength=(u + 1.0) * a[0],
        radius_source=source,
        radius_note=note,
        n_points_used=used,
        camera_span=span,
        ellipsoid=(prior.centre, prior.axes, prior.rotation),
        notes=notes,
    )


# --- evaluation ---------------------------------------------------------------------------------
def compare_to_truth(
    fit: CenterlineFit, true_points: np.ndarray, true_radius: np.ndarray
) -> dict[str, float]:
    """Mean distance of the estimated curve to the true one and mean relative radius error,
    over the estimated samples within the span the cameras cover and alongside the true curve
    (whose foot point is not past either of its ends). Empty when no sample qualifies."""
    truth = TubePrior(true_points, true_radius, open_ends=True, grid=False)
    lo, hi = fit.camera_span
    c = truth.closest(fit.points, exact=True)
    s_true = c["s"].numpy()
    sel = (fit.arclength >= lo) & (fit.arclength <= hi)
    sel &= (s_true >= 0) & (s_true <= truth.length)
    if sel.sum() < 2:
        return {}
    dist = c["dist"].numpy()[sel]
    r_true = c["radius"].numpy()[sel]
    r_est = fit.radius[sel]
    mean_r = float(np.mean(r_true))
    return {
        "centerline_mean_dist": float(np.mean(dist)),
        "centerline_mean_dist_pct_of_radius": float(100.0 * np.mean(dist) / mean_r),
        "radius_error_pct": float(100.0 * np.mean(np.abs(r_est - r_true) / r_true)),
        "true_mean_radius": mean_r,
        "compared_samples": float(sel.sum()),
    }


# --- figure -------------------------------------------------------------------------------------
def plot_centerline(
    path: Path,
    fit: CenterlineFit,
    centres: np.ndarray,
    points: np.ndarray,
    units: str,
    truth: tuple[np.ndarray, np.ndarray] | None = None,
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(12, 5.2))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    # The box around the curve and cameras, a radius and a half wider; data outside is clipped.
    pad = 1.5 * float(np.max(fit.radius))
    lo = np.min(np.concatenate([fit.points, centres]), 0) - pad
    hi = np.max(np.concatenate([fit.points, centres]), 0) + pad
    if fit.ellipsoid is not None:
        half = 1.1 * float(np.max(fit.ellipsoid[1]))
        lo, hi = fit.ellipsoid[0] - half, fit.ellipsoid[0] + half

    def clip(p: np.ndarray) -> np.ndarray:
        return p[np.all((p >= lo) & (p <= hi), axis=1)] if len(p) else p

    pts = _subsample(clip(points), 3000)
    if len(pts):
        ax.scatter(*pts.T, s=1, c="0.55", alpha=0.3, label="sparse points", depthshade=False)
    if truth is not None:
        ax.plot(*clip(truth[0]).T, color="tab:green", lw=1.2, ls="--", label="true centre line")
    ax.plot(*fit.points.T, color="tab:red", lw=2.0, label=f"estimated ({fit.kind})")
    if fit.ellipsoid is not None:
        c, a, rot = fit.ellipsoid
        u, v = np.meshgrid(np.linspace(0, np.pi, 13), np.linspace(0, 2 * np.pi, 25))
        sphere = np.stack([np.cos(u), np.sin(u) * np.cos(v), np.sin(u) * np.sin(v)], -1)
        e = c + (sphere * a) @ rot.T
        ax.plot_wireframe(e[..., 0], e[..., 1], e[..., 2], color="tab:red", lw=0.4, alpha=0.35)
    if len(centres):
        ax.scatter(*centres.T, s=8, color="tab:blue", label="cameras", depthshade=False)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(tuple(np.maximum(hi - lo, 1e-9)))
    ax.set_xlabel(f"x ({units})")
    ax.set_ylabel(f"y ({units})")
    ax.set_zlabel(f"z ({units})")
    ax.set_title("centre line, cameras and sparse points")
    ax.legend(loc="upper left", fontsize=8)

    ax2 = fig.add_subplot(1, 2, 2)
    ax2.axvspan(*fit.camera_span, color="tab:blue", alpha=0.08, label="camera span")
    if len(fit.bins[0]):
        ax2.plot(*fit.bins, "o", ms=3, color="0.5", label="per-slice estimate")
    ax2.plot(
        fit.arclength, fit.radius, color="tab:red", lw=2, label=f"radius ({fit.radius_source})"
    )
    if truth is not None and fit.kind == "tube":
        true_tube = TubePrior(truth[0], truth[1], grid=False)
        c = true_tube.closest(fit.points, exact=True)
        s_true = c["s"].numpy()
        alongside = (s_true > 0) & (s_true < true_tube.length)  # not past the truth's ends
        r_true = np.where(alongside, c["radius"].numpy(), np.nan)
        ax2.plot(fit.arclength, r_true, "--", color="tab:green", label="true radius")
    ax2.set_xlabel(f"arc length ({units})")
    ax2.set_ylabel(f"radius ({units})")
    ax2.set_ylim(0, float(np.max(fit.radius)) * 1.4)
    ax2.set_title(
        "radius along the curve" if fit.kind == "tube" else "section radius along the long axis"
    )
    ax2.grid(alpha=0.3)
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --- the stage ----------------------------------------------------------------------------------
class Centerline(Stage):
    """Centre curve and radius of the lumen (or an ellipsoid cavity) as the NeRF's prior."""

    name = "centerline"
    needs = ("poses",)
    version = 2
    Config = CenterlineConfig

    @classmethod
    def view(cls, folder: Path) -> CenterlineView:
        return CenterlineView(folder)

    def run(self, ctx: StageContext) -> CenterlineSummary:
        cfg: CenterlineConfig = ctx.config  # type: ignore[assignment]
        poses: PosesView = ctx.input("poses")
        centres = poses.centres()
        if len(centres) == 0:
            raise StageFailed("centerline: no registered cameras in 02_poses")
        view_dirs = np.array([poses.c2w[i][:3, 2] for i in poses.registered]).reshape(-1, 3)
        points = poses.points()
        units = poses.file.units
        fitter = fit_cavity if cfg.prior == "cavity" else fit_tube
        fit = fitter(centres, view_dirs, points, cfg, metric=poses.metric)
        for note in fit.notes:
            ctx.log(note)
        prior = fit.prior(cfg.far_radii)
        prior.save(ctx.out / "prior.npz")
        write_json(ctx.out / "centerline.json", fit.to_json(units))

        truth = None
        scores: dict[str, float] = {}
        if ctx.case.gt_dir and poses.metric:
            from endopipe.stages.io.ground_truth import GroundTruth

            gt_dir = Path(ctx.case.gt_dir)
            truth = (
                GroundTruth(gt_dir).centerline() if (gt_dir / "centerline.json").is_file() else None
            )
            if truth is not None and fit.kind == "tube":
                scores = compare_to_truth(fit, *truth)
        plot_centerline(ctx.out / "centerline.png", fit, centres, points, units, truth)
        summary = CenterlineSummary(
            kind=fit.kind,
            length=fit.length,
            mean_radius=prior.typical_radius
            if fit.kind == "cavity"
            else float(np.mean(fit.radius)),
            radius_source=fit.radius_source,
            radius_note=fit.radius_note,
            n_points_used=fit.n_points_used,
            n_cameras=len(centres),
            units=units,
            recentred_slices=fit.recentred_slices,
            **{k: v for k, v in scores.items() if k.startswith(("centerline_", "radius_"))},
        )
        ctx.log(
            f"{fit.kind}: length {fit.length:.1f} {units}, mean radius "
            f"{summary.mean_radius:.2f} {units} ({fit.radius_note})"
            + (
                f"; vs truth: {scores['centerline_mean_dist_pct_of_radius']:.1f}% of radius, "
                f"radius error {scores['radius_error_pct']:.1f}%"
                if scores
                else ""
            )
        )
        return summary


class CenterlineView:
    """Typed access to 03_centerline: the curve, and the prior for torch."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        data = json.loads((folder / "centerline.json").read_text())
        self.kind: str = data["kind"]
        self.units: str = data.get("units", "")
        self.points = np.asarray(data["points"], np.float64)
        self.radius = np.asarray(data["radius"], np.float64)
        self.arclength = np.asarray(data["arclength"], np.float64)

    def prior(self) -> LumenPrior:
        return LumenPrior.load(self.folder / "prior.npz")
