"""Which lumen prior the evidence supports: tube, cavity or none (`prior: auto`).

Why: a prior that does not fit the scene caps the rays short of the surface and pulls density
to a wall that is not there (on C3VD the tube's radius came from the 10% of the SfM
points near the short camera path, and the rendered depth at the points was 0.54-0.63 of
theirs). Each candidate is judged on ALL the SfM observations: the share of camera-to-point
rays whose exit through its wall lies within `fit_tolerance` of the point. The best candidate
is kept when that share reaches `min_fit`, and its share also scales L_prior's weight; below
it, no prior (weight 0) and ray bounds from the points alone.
"""

from __future__ import annotations

import numpy as np
import torch
from pydantic import BaseModel

from endopipe.stages.centerline.prior import LumenPrior


class PriorScore(BaseModel):
    """How well one candidate prior predicts how far the cameras saw the SfM points."""

    kind: str
    inlier_fraction: float  # observations whose wall exit is within tolerance of the point
    median_ratio: float  # median of (wall exit along the ray) / (point's distance)


class PriorChoice(BaseModel):
    """The prior used and why: what the summary and the report show."""

    kind: str  # tube | cavity | none
    forced: bool  # set by the config (tube / cavity), not chosen
    weight: float  # multiplies L_prior (the fit's inlier fraction; 0 for none)
    #: a forced prior that fits badly: the shape that fits, whose radius sets the scene's scale
    scale_from: str | None = None
    scores: list[PriorScore]
    reason: str


def score_prior(
    prior: LumenPrior, origins: np.ndarray, points: np.ndarray, tolerance: float
) -> PriorScore:
    """Cast a ray from each camera centre through each point it observed: where the ray
    leaves the prior's wall against where the point is. An observation is an inlier when the
    ratio lies within [1 / (1 + tolerance), 1 + tolerance]. Judged along the rays (what
    the NeRF's bounds and L_prior act on) and as a ratio, so candidates of any size compare
    fairly."""
    ratio = exit_ratios(prior, origins, points)
    if not len(ratio):
        return PriorScore(kind=prior.kind, inlier_fraction=0.0, median_ratio=float("nan"))
    band = np.log1p(tolerance)
    return PriorScore(
        kind=prior.kind,
        inlier_fraction=float(np.mean(np.abs(np.log(np.maximum(ratio, 1e-9))) <= band)),
        median_ratio=float(np.median(ratio)),
    )


def exit_ratios(prior: LumenPrior, origins: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Per camera-to-point ray: where it leaves the prior's wall / how far the point is."""
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    x = np.asarray(points, np.float64).reshape(-1, 3)
    dist = np.linalg.norm(x - o, axis=1)
    ok = dist > 1e-9
    o, x, dist = o[ok], x[ok], dist[ok]
    if not len(dist):
        return dist
    d = (x - o) / dist[:, None]
    cap = 1e3 * float(dist.max())
    _, far = prior.ray_bounds(o, d, margin=0.0, max_far=cap, near_fraction=1e-6)
    return far.double().numpy() / dist


def reaching_margin(
    prior: LumenPrior, origins: np.ndarray, points: np.ndarray, share: float
) -> float:
    """The least m such that the wall inflated by (1 + m) holds `share` of the points the
    cameras saw, measured along their rays (0 when the wall already does)."""
    ratio = exit_ratios(prior, origins, points)
    if not len(ratio):
        return 0.0
    return max(0.0, 1.0 / max(float(np.quantile(ratio, 1.0 - share)), 1e-6) - 1.0)


def empty_core(prior: LumenPrior, points: np.ndarray, share: float, iters: int = 12) -> float:
    """The widest core fraction f (`prior.in_core(x, f)`) that holds at most `share` of the
    points (bisection: the share inside grows with f). L_prior wants the core empty; where
    the points say tissue lies in it, a full-width core erases that tissue. Measured on C3VD,
    whose tube follows a scope sliding across its view: 8.2% of the observations lay in the
    half-radius core, 1.8% in a quarter-radius one; the bench colon's: 1.6%."""
    x = torch.as_tensor(np.asarray(points, np.float64).reshape(-1, 3), dtype=torch.float32)
    if not len(x):
        return 1.0

    def inside(f: float) -> float:
        return float(prior.in_core(x, f).float().mean())

    if inside(1.0) <= share:
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if inside(mid) <= share else (lo, mid)
    return lo


def choose_prior(
    candidates: dict[str, LumenPrior],
    origins: np.ndarray,
    points: np.ndarray,
    tolerance: float,
    min_fit: float,
    forced: str | None = None,
    insist: bool = False,
) -> PriorChoice:
    """The candidate that explains most points, or none when the best explains fewer than
    `min_fit` of them. `forced` (tube / cavity / none) is kept with its full weight, the user
    said what the anatomy is, unless the points contradict it: it explains fewer than `min_fit`
    of them while another shape explains more. Then the shape that fits is used, at its fit's
    weight, and the reason says so; with `insist` the forced prior is kept even then, called
    doubtful, and the scene's scale comes from the shape that fits (`scale_from`).

    Measured on the bench colon with the cavity preset (the ellipsoid explains 8% of the SfM
    depths, the tube 84%): kept at full weight, 43.8% of the mesh lay off the surface the
    cameras saw; with the tube's scale and bounds past the points, 31%; yielding to the tube
    (what `auto` picks), 15.8%."""
    scores = [score_prior(p, origins, points, tolerance) for p in candidates.values()]
    ranked = sorted(scores, key=lambda s: -s.inlier_fraction)
    listing = ", ".join(
        f"{s.kind} {100 * s.inlier_fraction:.0f}% of SfM depths within {100 * tolerance:.0f}%"
        for s in ranked
    )
    if forced == "none":
        return PriorChoice(
            kind="none",
            forced=True,
            weight=0.0,
            scores=scores,
            reason=f"none set by the config ({listing})",
        )
    if forced is not None:
        reason = f"{forced} set by the config ({listing})"
        own = next((s.inlier_fraction for s in scores if s.kind == forced), None)
        best = ranked[0] if ranked else None
        scale_from = None
        if own is not None and best is not None and own < min_fit <= best.inlier_fraction:
            contrast = (
                f"it predicts only {100 * own:.0f}% of the SfM depths where {best.kind} "
                f"predicts {100 * best.inlier_fraction:.0f}%"
            )
            if not insist:
                return PriorChoice(
                    kind=best.kind,
                    forced=False,
                    weight=best.inlier_fraction,
                    scores=scores,
                    reason=f"{forced} set by the config, but the SfM points contradict it: "
                    f"{contrast}, so the {best.kind} is used ({listing}; centerline.insist=true "
                    f"keeps the {forced})",
                )
            scale_from = best.kind
            reason += (
                f"; doubtful: {contrast} (centerline.prior=auto would use the {best.kind}); "
                f"the scene's scale is the {best.kind}'s"
            )
        return PriorChoice(
            kind=forced,
            forced=True,
            weight=1.0,
            scores=scores,
            reason=reason,
            scale_from=scale_from,
        )
    best = ranked[0] if ranked else None
    if best is None or best.inlier_fraction < min_fit:
        return PriorChoice(
            kind="none",
            forced=False,
            weight=0.0,
            scores=scores,
            reason=f"no prior fits: {listing}; needed {100 * min_fit:.0f}%",
        )
    return PriorChoice(
        kind=best.kind,
        forced=False,
        weight=best.inlier_fraction,
        scores=scores,
        reason=f"{best.kind} fits best: {listing}",
    )


def point_reach(
    c2w: dict[int, np.ndarray],
    frame_of_obs: np.ndarray,
    xyz_of_obs: np.ndarray,
    percentile: float = 98.0,
) -> float:
    """How far the cameras see: the largest per-frame `percentile` of the distance from a
    camera to the points it observed, in world units (0 when no frame saw 3 points)."""
    reach = 0.0
    for i, pose in c2w.items():
        seen = np.asarray(xyz_of_obs)[np.asarray(frame_of_obs) == i]
        if len(seen) < 3:
            continue
        d = np.linalg.norm(seen - np.asarray(pose)[:3, 3], axis=1)
        reach = max(reach, float(np.percentile(d, percentile)))
    return reach
