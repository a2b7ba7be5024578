"""Re-score finished cases' depth maps against their ground truth as read today, and say where
along the image radius the error sits (docs/results.md: C3VD re-scored, its radial error, the lens).

    .venv/bin/python scripts/rescore_depth.py WORKDIR/CASE [WORKDIR/CASE ...] [--lens-check]

The depth stage's own evaluation (ours and the two guesses on the same pixels) over each case's
05_depth maps, without re-rendering: what a change of a ground-truth reader does to old runs.
Then, for a relative ground truth (C3VD's panel), the signed error of our per-frame
affinely-aligned depth binned by the distance to the principal point (1 = half the frame
height). `--lens-check` (a diagnosis that uses the C3VD calibration, not a pipeline result):
our per-pixel range re-projected to z-depth through C3VD's own omnidirectional lens, for a few
guesses of how much of the 1080-px frame height the preview kept. `--far`: the far lumen alone,
each frame's pixels in the panel's deepest 30% (Spearman of ours inside them against the panel,
and the whole frame's affinely aligned depth's AbsRel there), beside the image brightness as a
cue (the depth stage's brightness guess) on the same pixels.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from endopipe.stages.camera.rays import image_directions
from endopipe.stages.depth.evaluate import evaluate, ground_truth_depths
from endopipe.stages.depth.view import DepthView
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.metrics.baselines import brightness_guess
from endopipe.stages.metrics.depth import affine_fit, affine_sequence_metrics
from endopipe.stages.poses.view import PosesView

# C3VD's colonoscope (PROVENANCE.md of the preview): Scaramuzza polynomial at 1350x1080.
C3VD_POLY = (767.73, 0.0, -5.925e-4, -2.694e-7, -2.164e-10)
C3VD_HEIGHT = 1080.0
FAR_SHARE = 0.3  # the far lumen: each frame's deepest 30% of the panel's pixels
RADIAL_BINS = (0.0, 0.2, 0.4, 0.6, 0.8, 1.0, 1.2, 1.5)
BANDS = list(zip(RADIAL_BINS[:-1], RADIAL_BINS[1:], strict=True))


def c3vd_angle(radius_px: np.ndarray) -> np.ndarray:
    """The angle to the optical axis of a pixel `radius_px` from the centre (1080-px frame)."""
    z = sum(a * radius_px**k for k, a in enumerate(C3VD_POLY))
    return np.arctan2(radius_px, z)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", type=Path, nargs="+")
    parser.add_argument("--lens-check", action="store_true")
    parser.add_argument("--far", action="store_true", help="score the far lumen alone")
    args = parser.parse_args()
    for case in args.cases:
        ingest = IngestView(case / "01_ingest")
        camera = PosesView(case / "02_poses").intrinsics
        depth = DepthView(case / "05_depth")
        gt = ingest.ground_truth()
        ids = [i for i in range(len(ingest.frames)) if depth.has_depth(i)]
        truth = ground_truth_depths(gt, ingest, ids)
        ours = {i: depth.depth(i) for i in ids}
        metrics = evaluate(gt, ingest, ours, truth, {}, principal=(camera.cx, camera.cy))
        block = "affine_invariant" if metrics.get("gt_kind") == "relative" else "median_scaled"
        scores = {"ours": metrics[block]} | {
            k: v[block] for k, v in metrics.get("baselines", {}).items()
        }
        print(case)
        for name, m in scores.items():
            print(f"  {name:10s} " + "  ".join(f"{k} {v:.3f}" for k, v in m.items()))
        if block != "affine_invariant":
            continue
        fov = ingest.fov() > 0
        h, w = fov.shape
        v, u = np.mgrid[0:h, 0:w]
        radius = np.hypot(u - camera.cx, v - camera.cy)
        errors: list[list[float]] = [[] for _ in BANDS]
        for i in sorted(truth):
            g, d = truth[i], ours[i]
            valid = fov & (d > 0) & (g > 0)
            scale, shift = affine_fit(d[valid].astype(float), g[valid].astype(float))
            signed = (scale * d + shift - g) / np.maximum(g, 1e-6)
            for b, (lo, hi) in enumerate(BANDS):
                inside = valid & (radius >= lo * h / 2) & (radius < hi * h / 2)
                if inside.sum() > 20:
                    errors[b].append(float(signed[inside].mean()))
        if args.far:
            print_far_lumen(ingest, truth, ours, fov)
        print("  signed error of the aligned depth by radius (1 = half the height):")
        for (lo, hi), e in zip(BANDS, errors, strict=True):
            print(f"    {lo:.1f}-{hi:.1f}: {np.mean(e):+.3f}" if e else f"    {lo:.1f}-{hi:.1f}: -")
        if not args.lens_check:
            continue
        dirs = image_directions(camera)
        length = np.linalg.norm(dirs, axis=-1)  # range = z-depth x |direction with z = 1|
        for kept in (2 / 3, 0.75, 8 / 9, 1.0):
            angle = c3vd_angle(radius * kept * C3VD_HEIGHT / h)
            z = [np.where(ours[i] > 0, ours[i] * length * np.cos(angle), 0) for i in sorted(truth)]
            m = affine_sequence_metrics(z, [truth[i] for i in sorted(truth)], [fov] * len(z), ids)
            a = m["affine_invariant"]
            print(
                f"  range through C3VD's lens, preview = {kept:.2f} of the frame height: "
                f"spearman {a['spearman']:.3f} abs_rel {a['abs_rel']:.3f}"
            )


def print_far_lumen(
    ingest: IngestView, truth: dict[int, np.ndarray], ours: dict[int, np.ndarray], fov: np.ndarray
) -> None:
    """Per-frame scores inside the panel's deepest FAR_SHARE of pixels, averaged over frames."""
    from scipy.stats import spearmanr

    rho, cue, rel = [], [], []
    for i in sorted(truth):
        g, d = truth[i], ours[i]
        valid = fov & (d > 0) & (g > 0)
        if valid.sum() < 100:
            continue
        far = valid & (g >= np.quantile(g[valid], 1.0 - FAR_SHARE))
        scale, shift = affine_fit(d[valid].astype(float), g[valid].astype(float))
        rho.append(spearmanr(d[far], g[far]).statistic)
        cue.append(spearmanr(brightness_guess(ingest.image(i))[far], g[far]).statistic)
        rel.append(float(np.mean(np.abs(scale * d[far] + shift - g[far]) / g[far])))
    print(
        f"  far lumen (the panel's deepest {FAR_SHARE:.0%}, {len(rho)} frames): spearman "
        f"{np.mean(rho):.3f} (frames {np.percentile(rho, 10):.2f}-{np.percentile(rho, 90):.2f}), "
        f"aligned abs_rel {np.mean(rel):.3f}; brightness cue spearman {np.mean(cue):.3f}"
    )


if __name__ == "__main__":
    main()
