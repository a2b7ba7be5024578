"""The fitted centre line against a ground-truth one (gt/centerline.json)."""

from __future__ import annotations

import numpy as np

from endopipe.stages.centerline.fit import CenterlineFit
from endopipe.stages.centerline.prior import TubePrior


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
