"""centerline: the lumen's centre curve and radius from the camera path and the sparse points.

Seed §3.3: the anatomical prior is "a generalized tube model that follows the approximate path of
the camera". This stage estimates it once, so the NeRF stage can use it as a signed-distance
proxy (prior/):

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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from endopipe.stages.centerline.config import CenterlineConfig
from endopipe.stages.centerline.fit import (
    MAD_TO_SIGMA,
    CenterlineFit,
    default_radius,
    robust_inliers,
    subsample,
)
from endopipe.stages.centerline.prior import TubePrior


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
    points = subsample(np.asarray(points, np.float64).reshape(-1, 3), cfg.max_points)
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
