"""Depth metrics (DESIGN §6): AbsRel, SqRel, RMSE, RMSElog, delta thresholds.

Per-frame median scaling (the monocular protocol) or one scale for the whole sequence; a frame's
metrics use the pixels where the ground truth is valid (> 0), the prediction is positive and the
optional mask is set.
"""

from __future__ import annotations

import numpy as np

KEYS = ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")


def depth_errors(pred: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """Metrics of matched 1-D arrays of positive depths."""
    pred = np.asarray(pred, np.float64)
    gt = np.asarray(gt, np.float64)
    ratio = np.maximum(gt / pred, pred / gt)
    return {
        "abs_rel": float(np.mean(np.abs(gt - pred) / gt)),
        "sq_rel": float(np.mean((gt - pred) ** 2 / gt)),
        "rmse": float(np.sqrt(np.mean((gt - pred) ** 2))),
        "rmse_log": float(np.sqrt(np.mean((np.log(gt) - np.log(pred)) ** 2))),
        "a1": float(np.mean(ratio < 1.25)),
        "a2": float(np.mean(ratio < 1.25**2)),
        "a3": float(np.mean(ratio < 1.25**3)),
    }


def valid_pixels(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    v = (gt > 0) & np.isfinite(gt) & (pred > 0) & np.isfinite(pred)
    if mask is not None:
        v &= mask.astype(bool)
    return v


def frame_metrics(
    pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None, scale: float | str = "median"
) -> dict[str, float]:
    """One frame: scale "median" (per-frame median ratio), or a number (1.0: as is)."""
    v = valid_pixels(pred, gt, mask)
    if not v.any():
        return {k: float("nan") for k in KEYS}
    p, g = pred[v], gt[v]
    s = float(np.median(g) / np.median(p)) if scale == "median" else float(scale)
    out = depth_errors(p * s, g)
    out["scale"] = s
    out["valid_fraction"] = float(v.mean())
    return out


def sequence_metrics(
    preds: list[np.ndarray], gts: list[np.ndarray], masks: list[np.ndarray | None] | None = None
) -> dict[str, dict[str, float]]:
    """Both protocols over frames: {"median_scaled": mean of per-frame metrics, "sequence_scaled":
    one median-ratio scale for all frames, "unscaled": as rendered}."""
    masks = masks or [None] * len(preds)
    per = [frame_metrics(p, g, m) for p, g, m in zip(preds, gts, masks, strict=True)]
    ratios = []
    for p, g, m in zip(preds, gts, masks, strict=True):
        v = valid_pixels(p, g, m)
        if v.any():
            ratios.append(g[v] / p[v])
    s = float(np.median(np.concatenate(ratios))) if ratios else 1.0
    seq = [frame_metrics(p, g, m, scale=s) for p, g, m in zip(preds, gts, masks, strict=True)]
    raw = [frame_metrics(p, g, m, scale=1.0) for p, g, m in zip(preds, gts, masks, strict=True)]

    def mean(rows: list[dict]) -> dict[str, float]:
        return {k: float(np.nanmean([r[k] for r in rows])) for k in KEYS}

    return {
        "median_scaled": mean(per),
        "sequence_scaled": {**mean(seq), "scale": s},
        "unscaled": mean(raw),
    }
