"""`prior: cavity` (stomach): the lumen as an ellipsoid fitted to the sparse points (robust
algebraic fit, refined by robust least squares on the point-to-ellipsoid distance), with a
second-moment fallback when the fit is implausible.
"""

from __future__ import annotations

import numpy as np

from endopipe.stages.centerline.config import CenterlineConfig
from endopipe.stages.centerline.fit import CenterlineFit, default_radius, robust_inliers, subsample
from endopipe.stages.centerline.prior import EllipsoidPrior


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
    points = subsample(np.asarray(points, np.float64).reshape(-1, 3), cfg.max_points)
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
