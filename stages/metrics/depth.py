"""Evaluation metrics, defined once (docs/formats.md). Plain functions over arrays, no I/O.

Poses: fraction registered, absolute trajectory error after a sim3 (Umeyama) alignment, relative
rotation error between consecutive frames.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from endopipe.stages.camera import rotation_angle_deg, umeyama


def registered_fraction(registered: int, total: int) -> float:
    """Share of the frames that received a pose."""
    return registered / total if total else 0.0


def path_length(centres: np.ndarray) -> float:
    """Length of the polyline through the camera centres (Nx3), in their units."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    return float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum()) if len(c) > 1 else 0.0


def ate_rmse(est_centres: np.ndarray, gt_centres: np.ndarray, with_scale: bool = True) -> float:
    """Absolute trajectory error: RMSE of camera centres after a sim3 (or SE3) alignment to GT.

    The result is in the ground truth's units.
    """
    est = np.asarray(est_centres, dtype=np.float64).reshape(-1, 3)
    gt = np.asarray(gt_centres, dtype=np.float64).reshape(-1, 3)
    if len(est) != len(gt) or len(est) < 3:
        raise ValueError("ATE needs at least 3 matching camera centres")
    s, R, t = umeyama(est, gt, with_scale=with_scale)
    aligned = s * est @ R.T + t
    return float(np.sqrt(np.mean(np.sum((aligned - gt) ** 2, axis=1))))


def relative_rotation_error_deg(est_c2w: list[np.ndarray], gt_c2w: list[np.ndarray]) -> float:
    """Mean angle (degrees) between estimated and true rotations from each frame to the next.

    Frame-to-frame rotations do not depend on the world frame, so no alignment is needed.
    """
    if len(est_c2w) != len(gt_c2w):
        raise ValueError("RRE needs as many estimated as ground-truth poses")
    errors = []
    for k in range(len(est_c2w) - 1):
        rel_est = est_c2w[k][:3, :3].T @ est_c2w[k + 1][:3, :3]
        rel_gt = gt_c2w[k][:3, :3].T @ gt_c2w[k + 1][:3, :3]
        errors.append(rotation_angle_deg(rel_est.T @ rel_gt))
    return float(np.mean(errors)) if errors else 0.0


def pose_metrics(est: dict[int, np.ndarray], gt: dict[int, np.ndarray]) -> dict[str, float]:
    """ATE (after sim3), ATE as % of the GT path, RRE and the sim3 scale, over common frames.

    `est` and `gt` map a frame index to a camera-to-world 4x4; only frames in both count, in
    index order. ATE is in the units of `gt`.
    """
    common = sorted(set(est) & set(gt))
    if len(common) < 3:
        raise ValueError("pose metrics need at least 3 frames with both a pose and ground truth")
    e = np.array([est[i][:3, 3] for i in common])
    g = np.array([gt[i][:3, 3] for i in common])
    s, _, _ = umeyama(e, g)
    ate = ate_rmse(e, g)
    length = path_length(g)
    return {
        "ate": ate,
        "ate_percent_of_path": 100.0 * ate / length if length > 0 else float("nan"),
        "rre_deg": relative_rotation_error_deg([est[i] for i in common], [gt[i] for i in common]),
        "gt_path_length": length,
        "sim3_scale": s,
        "frames": len(common),
    }


# ------------------------------------------------------------------- depth (docs/formats.md)

DEPTH_KEYS = ("abs_rel", "sq_rel", "rmse", "rmse_log", "delta1", "delta2", "delta3")


def depth_errors(pred: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """AbsRel, SqRel, RMSE, RMSElog and the δ thresholds over matched positive depths."""
    pred = np.asarray(pred, np.float64)
    gt = np.asarray(gt, np.float64)
    ratio = np.maximum(gt / pred, pred / gt)
    return {
        "abs_rel": float(np.mean(np.abs(gt - pred) / gt)),
        "sq_rel": float(np.mean((gt - pred) ** 2 / gt)),
        "rmse": float(np.sqrt(np.mean((gt - pred) ** 2))),
        "rmse_log": float(np.sqrt(np.mean((np.log(gt) - np.log(pred)) ** 2))),
        "delta1": float(np.mean(ratio < 1.25)),
        "delta2": float(np.mean(ratio < 1.25**2)),
        "delta3": float(np.mean(ratio < 1.25**3)),
    }


def gt_pixels(gt: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Pixels where the ground truth is valid (> 0, finite) and the mask set: what a
    prediction is asked to cover."""
    v = (gt > 0) & np.isfinite(gt)
    return v & mask.astype(bool) if mask is not None else v


def valid_depth_pixels(
    pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None
) -> np.ndarray:
    """Pixels where the ground truth is valid (> 0), the prediction positive, the mask set."""
    return gt_pixels(gt, mask) & (pred > 0) & np.isfinite(pred)


def coverage(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Share of the valid ground-truth pixels inside the mask that got a depth (positive and
    finite; 0 = no depth): every other metric is computed on these pixels only, so a map
    with holes must say how much it left out. NaN when no pixel has ground truth."""
    asked = gt_pixels(gt, mask)
    n = int(asked.sum())
    return float(valid_depth_pixels(pred, gt, mask).sum() / n) if n else float("nan")


def _mean_coverage(rows: list[dict]) -> float:
    """Mean coverage over the frames that have ground truth (a frame with no depth at all
    counts as 0, not as missing)."""
    values = [r["coverage"] for r in rows if np.isfinite(r.get("coverage", np.nan))]
    return float(np.mean(values)) if values else float("nan")


def depth_frame_metrics(
    pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None, scale: float | None = None
) -> dict[str, float]:
    """One frame; `scale` None = per-frame median scaling, a number = that scale (1.0: as is).
    `valid` is the share of the image scored, `coverage` the share of the ground truth."""
    v = valid_depth_pixels(pred, gt, mask)
    cover = coverage(pred, gt, mask)
    if not v.any():
        nan = float("nan")
        return {k: nan for k in DEPTH_KEYS} | {"scale": nan, "valid": 0.0, "coverage": cover}
    p, g = pred[v], gt[v]
    s = float(np.median(g) / np.median(p)) if scale is None else float(scale)
    return depth_errors(p * s, g) | {"scale": s, "valid": float(v.mean()), "coverage": cover}


def depth_sequence_metrics(
    preds: list[np.ndarray],
    gts: list[np.ndarray],
    masks: list[np.ndarray | None] | None = None,
    ids: list[int] | None = None,
    unscaled: bool = False,
) -> dict:
    """Both protocols of docs/formats.md: per-frame median scaling, and one median-ratio scale for
    the whole sequence (stricter: it rewards a 3D-consistent reconstruction). Mean and per frame.
    `unscaled` adds the depths as they are (meaningful when the poses are metric). Each block
    carries `coverage` (see `coverage`); the error metrics are means over covered pixels.
    """
    masks = masks if masks is not None else [None] * len(preds)
    ids = ids if ids is not None else list(range(len(preds)))
    ratios = [
        g[v] / p[v]
        for p, g, m in zip(preds, gts, masks, strict=True)
        if (v := valid_depth_pixels(p, g, m)).any()
    ]
    seq_scale = float(np.median(np.concatenate(ratios))) if ratios else 1.0
    per_frame = []
    for i, p, g, m in zip(ids, preds, gts, masks, strict=True):
        per_frame.append(
            {
                "index": i,
                "median_scaled": depth_frame_metrics(p, g, m),
                "sequence_scaled": depth_frame_metrics(p, g, m, scale=seq_scale),
            }
            | ({"unscaled": depth_frame_metrics(p, g, m, scale=1.0)} if unscaled else {})
        )

    def mean(protocol: str) -> dict[str, float]:
        rows = [f[protocol] for f in per_frame if f[protocol]["valid"] > 0]
        return {
            k: float(np.mean([r[k] for r in rows])) if rows else float("nan") for k in DEPTH_KEYS
        } | {"coverage": _mean_coverage([f[protocol] for f in per_frame])}

    return {
        "median_scaled": mean("median_scaled"),
        "sequence_scaled": mean("sequence_scaled") | {"scale": seq_scale},
        **({"unscaled": mean("unscaled")} if unscaled else {}),
        "frames": len(per_frame),
        "per_frame": per_frame,
    }


# --------------------------------------------------------------------------------- images


def image_metrics(
    pred: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None
) -> dict[str, float]:
    """PSNR (masked MSE) and SSIM (kornia, 11x11 Gaussian window, mean over the mask) of two
    HxWx3 float images in [0, 1]."""
    import kornia
    import torch

    p = torch.as_tensor(np.clip(pred, 0, 1), dtype=torch.float32).permute(2, 0, 1)[None]
    t = torch.as_tensor(np.clip(target, 0, 1), dtype=torch.float32).permute(2, 0, 1)[None]
    m = (
        torch.ones_like(p[:, :1])
        if mask is None
        else torch.as_tensor(mask, dtype=torch.float32)[None, None]
    )
    mse = (((p - t) ** 2) * m).sum() / (m.sum() * 3).clamp_min(1)
    psnr = float(10 * torch.log10(1.0 / mse.clamp_min(1e-12)))
    ssim_map = kornia.metrics.ssim(p, t, window_size=11, max_val=1.0)
    ssim = float((ssim_map * m).sum() / (m.sum() * 3).clamp_min(1))
    return {"psnr": psnr, "ssim": ssim}


def affine_fit(pred: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """Least-squares scale and shift mapping matched 1-D `pred` onto `gt`."""
    a = np.stack([pred, np.ones_like(pred)], 1)
    (scale, shift), *_ = np.linalg.lstsq(a, gt, rcond=None)
    return float(scale), float(shift)


def affine_invariant_metrics(
    pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None
) -> dict[str, float]:
    """Against a ground truth known only up to an affine map (C3VD's grey depth panel): AbsRel
    after the least-squares scale and shift that map the prediction onto the ground truth, and
    Spearman's rank correlation (invariant to any monotonic map)."""
    from scipy.stats import spearmanr

    v = valid_depth_pixels(pred, gt, mask)
    n = int(v.sum())
    cover = coverage(pred, gt, mask)
    if n < 10:
        return {"abs_rel": float("nan"), "spearman": float("nan"), "valid": n, "coverage": cover}
    p, g = pred[v].astype(np.float64), gt[v].astype(np.float64)
    scale, shift = affine_fit(p, g)
    aligned = scale * p + shift
    return {
        "abs_rel": float(np.mean(np.abs(aligned - g) / g)),
        "spearman": float(spearmanr(p, g).statistic),
        "scale": float(scale),
        "shift": float(shift),
        "valid": n,
        "coverage": cover,
    }


def affine_sequence_metrics(
    preds: list[np.ndarray],
    gts: list[np.ndarray],
    masks: list[np.ndarray | None],
    ids: list[int],
) -> dict:
    """Per-frame affine-invariant metrics and their means (frames with too few valid pixels
    are left out of the means, but not out of the mean coverage)."""
    per_frame = [
        {"index": i, **affine_invariant_metrics(p, g, m)}
        for i, p, g, m in zip(ids, preds, gts, masks, strict=True)
    ]
    rows = [f for f in per_frame if f["valid"] >= 10]
    mean = {
        k: float(np.mean([r[k] for r in rows])) if rows else float("nan")
        for k in ("abs_rel", "spearman")
    } | {"coverage": _mean_coverage(per_frame)}
    return {"affine_invariant": mean, "frames": len(per_frame), "per_frame": per_frame}


def sequence_protocol(gt: object | None, metric: bool = False):
    """The sequence scoring a ground truth supports (its `kind`, stages/io/ground_truth.py): a
    relative one (an affine proxy of depth) no metric protocol, only the affine-invariant one;
    the others both scaled protocols, and the depth as it is when the poses are `metric`. Called
    as `(preds, gts, masks, ids)`."""
    if getattr(gt, "kind", "exact") == "relative":
        return affine_sequence_metrics
    return partial(depth_sequence_metrics, unscaled=True) if metric else depth_sequence_metrics
