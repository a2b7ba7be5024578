"""centerline.png: the curve, cameras and points in 3-D, and the radius along the curve."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from endopipe.stages.centerline.fit import CenterlineFit, subsample
from endopipe.stages.centerline.prior import TubePrior


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

    pts = subsample(clip(points), 3000)
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
