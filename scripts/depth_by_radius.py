"""Where a run's depth error lies by distance from the image centre, against relative ground truth
(docs/results.md: C3VD, whose error is mostly the outer ring).

Run: `.venv/bin/python scripts/depth_by_radius.py WORKDIR/CASE` on a case whose depth stage
scored a relative (affine) ground truth, such as `endopipe run ../shared/data/c3vd_v3_preview`.
A diagnosis, not a test. Radius bands are fractions of the half image height from the principal
point. Per band:
- ours: the share of pixels, the mean SSI-AbsRel (each frame's own scale and shift, as the
  depth stage fits them over all its pixels), that band's share of the summed error, and the
  signed error (positive: ours too far);
- the SfM points: the same signed and absolute errors of the points' own depth at their pixels,
  after a robust per-frame fit of the ground truth to the points alone (are the points, not only
  the field, off there?);
- the scores on the pixels within the radius the lens was fitted within (`cameras.json`
  `fitted_radius_px`) and past it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from endopipe.stages.depth.evaluate import ground_truth_depths, inside_view
from endopipe.stages.depth.view import DepthView
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.metrics.depth import affine_fit, affine_invariant_metrics
from endopipe.stages.poses.view import PosesView

BANDS = (0.0, 0.4, 0.6, 0.8, 0.9, 1.0, 1.1, 1.5)


def band_of(radius: np.ndarray) -> np.ndarray:
    return np.digitize(radius, BANDS[1:-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("case", type=Path, help="a case folder (the one with 05_depth)")
    case = parser.parse_args().case
    ingest, poses = IngestView(case / "01_ingest"), PosesView(case / "02_poses")
    depth = DepthView(case / "05_depth")
    truth = ground_truth_depths(ingest.ground_truth(), ingest, depth.indices)
    inside = inside_view(ingest)
    k = poses.intrinsics.scaled(ingest.width, ingest.height)
    u, v = np.meshgrid(np.arange(ingest.width), np.arange(ingest.height))
    radius = np.hypot(u - k.cx, v - k.cy)
    bands = band_of(radius / (ingest.height / 2))
    n = len(BANDS) - 1
    err, count, signed = np.zeros(n), np.zeros(n), [[] for _ in range(n)]
    within: dict[str, list[float]] = {"within": [], "past": [], "rho within": []}
    fitted = poses.file.fitted_radius_px
    if fitted is not None:
        fitted *= ingest.width / poses.file.width
    for i in depth.indices:
        d, g = depth.depth(i), truth.get(i)
        if g is None:
            continue
        valid = (d > 0) & (g > 0) & inside
        if valid.sum() < 10:
            continue
        scale, shift = affine_fit(d[valid].astype(float), g[valid].astype(float))
        rel = (scale * d[valid] + shift - g[valid]) / g[valid]
        b = bands[valid]
        for j in range(n):
            m = b == j
            err[j] += np.abs(rel[m]).sum()
            count[j] += m.sum()
            if m.any():
                signed[j].append(float(np.mean(rel[m])))
        if fitted is not None:
            near = radius <= fitted
            scores = affine_invariant_metrics(np.where(near & inside, d, 0), g)
            within["within"].append(scores["abs_rel"])
            within["rho within"].append(scores["spearman"])
            far = valid & ~near
            if far.sum() >= 10:
                aligned = scale * d[far] + shift
                within["past"].append(float(np.mean(np.abs(aligned - g[far]) / g[far])))
    points = sfm_points_by_band(case, ingest, poses, truth, inside, k)
    head = f"{'band':>10} {'pixels':>7} {'SSI-AbsRel':>10} {'error share':>11} {'signed':>7}"
    print(head + "   SfM points: n, |err|, signed")
    for j in range(n):
        if not count[j]:
            continue
        p = points[j]
        sfm = f"{len(p):6d} {np.median(np.abs(p)):.3f} {np.median(p):+.3f}" if len(p) else "     -"
        print(
            f"{BANDS[j]:.1f}-{BANDS[j + 1]:.1f} {count[j] / count.sum():7.3f} "
            f"{err[j] / count[j]:10.3f} {err[j] / err.sum():11.3f} "
            f"{np.mean(signed[j]):+7.3f}   {sfm}"
        )
    if within["within"]:
        print(
            f"within the fitted radius ({fitted:.0f} px): SSI-AbsRel "
            f"{np.mean(within['within']):.4f}, "
            f"Spearman {np.mean(within['rho within']):.4f}; past it: SSI-AbsRel "
            f"{np.mean(within['past']) if within['past'] else float('nan'):.4f} (the frame's fit)"
        )


def sfm_points_by_band(case, ingest, poses, truth, inside, k) -> list[np.ndarray]:
    """Per band, the SfM points' relative error against the ground truth at their pixels, after
    a per-frame fit of the truth to the points (refit on the points within 3x the median
    error)."""
    obs = poses.observations(ingest.index_by_name())
    out: list[list[float]] = [[] for _ in range(len(BANDS) - 1)]
    if obs is None:
        return [np.zeros(0) for _ in out]
    sx, sy = ingest.width / poses.file.width, ingest.height / poses.file.height
    for i in np.unique(obs.frame):
        g = truth.get(int(i))
        if g is None or int(i) not in poses.c2w:
            continue
        sel = obs.frame == i
        w2c = np.linalg.inv(poses.c2w[int(i)])
        z = obs.xyz[sel] @ w2c[2, :3] + w2c[2, 3]
        col = np.clip(np.rint(obs.uv[sel, 0] * sx).astype(int), 0, ingest.width - 1)
        row = np.clip(np.rint(obs.uv[sel, 1] * sy).astype(int), 0, ingest.height - 1)
        gg = g[row, col]
        ok = (z > 0) & (gg > 0) & inside[row, col]
        if ok.sum() < 20:
            continue
        z, gg, row, col = z[ok], gg[ok].astype(float), row[ok], col[ok]
        scale, shift = affine_fit(z, gg)
        rel = (scale * z + shift - gg) / gg
        keep = np.abs(rel) < 3 * np.median(np.abs(rel)) + 1e-9
        scale, shift = affine_fit(z[keep], gg[keep])
        rel = (scale * z + shift - gg) / gg
        b = band_of(np.hypot(col - k.cx, row - k.cy) / (ingest.height / 2))
        for j, r in zip(b, rel, strict=True):
            out[j].append(float(r))
    return [np.asarray(x) for x in out]


if __name__ == "__main__":
    main()
