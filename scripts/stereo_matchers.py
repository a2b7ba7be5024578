"""Which CPU stereo matcher, at which resolution, gives the best metric depth: endopipe's own
(stages/ingest/stereo.py: StereoSGBM 3-way, left-right checked, at the working size) against
OpenCV's other SGBM modes and block sizes, StereoBM, a disparity median filter and the WLS
filter of opencv-contrib, each at the working size and at the source's.

    .venv/bin/python scripts/stereo_matchers.py CASE [CASE ...] [--sizes working source]
        [--frames 10] [--every 1] [--scale none|median] [--only REGEX] [--blocks 3 5 7]

Why: the depth is only as good as the matcher, and unsure pixels must stay unknown (0), so a
matcher is judged on both its error and what it leaves out. Each CASE is an input endopipe
reads with right views (Hamlyn's image01/ image02/, a SCARED keyframe, `endopipe synth
--layout hamlyn|scared --stereo`); its truth is what the reader gives (synthetic gt/: exact
z-depth in mm; Hamlyn's depth01: a reference, scored with `--scale median`).

The pair is paired and mended as ingest does it (rig_check.py, at the working size; its row
shift scaled to the size matched). Every depth is scored at the working size (the source's
longer side brought to 320 px, as ingest does): a depth matched at another size is brought there
by nearest pixel, and so is the truth, so each size is scored on the same pixels. Columns:
AbsRel, mean |d - t| / t over the pixels both have (mean over frames); coverage, the share of
the truth's pixels with a depth; good2 / good5, the share of the truth's pixels with a depth
within 2% / 5%; bias, the median t / d (1: metric; with --scale median each frame's depth is
first multiplied by its own); ms per pair (the matching alone, one thread; the fastest of
--repeat runs). Matched at another size than the working one, the settings given in
working-size pixels (min_disparity_px, the speckle filter's window and range; with --scale-lr
the left-right tolerance too) are scaled to it, except `ours, default cfg`, matched with
StereoConfig() as it is.

WLS (cv2.ximgproc) needs opencv-contrib: run with PYTHONPATH pointing at a copy of
opencv-contrib-python-headless installed apart (`pip install --no-deps --target DIR`); without
it the WLS rows are skipped with a line saying so. WLS fills every pixel: it is also scored with
its confidence map thresholded, and masked by the raw matches' left-right check.
"""

from __future__ import annotations

import argparse
import csv
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2  # noqa: I001  (before endopipe: a PYTHONPATH copy of opencv-contrib wins)
import numpy as np

import endopipe.stages  # noqa: F401  (cv2 first)
from endopipe.stages.camera import Camera
from endopipe.stages.ingest.config import StereoConfig
from endopipe.stages.ingest.rig_check import RigCheck, check_rig, mended_right
from endopipe.stages.ingest.selection import resize, working_size
from endopipe.stages.ingest.stereo import (
    MODES,
    SUBPIXEL,
    consistent,
    disparity_range,
    grey,
    match_depth,
    matcher,
    padded_match,
)
from endopipe.stages.io.sources import open_input

WORKING_MAX = 320  # ingest.max_size's default
PREFILTERS = {
    "xsobel": cv2.STEREO_BM_PREFILTER_XSOBEL,
    "norm": cv2.STEREO_BM_PREFILTER_NORMALIZED_RESPONSE,
}

#: (left RGB, right RGB, fx, baseline mm, cfg) -> {row name suffix: depth (mm, 0 unknown)}
Matcher = Callable[[np.ndarray, np.ndarray, float, float, StereoConfig], dict[str, np.ndarray]]


@dataclass
class Pair:
    """One rectified pair at the source's size, its truth (mm, 0 unknown) and camera."""

    name: str
    left: np.ndarray
    right: np.ndarray
    truth: np.ndarray
    camera: Camera
    baseline_mm: float
    rig: RigCheck


# ------------------------------------------------------------------------------ the matchers


def sgbm(n: int, block: int, mode: str, cfg: StereoConfig) -> cv2.StereoSGBM:
    """StereoSGBM set as stereo.matcher sets it, with another mode and block."""
    return matcher(n, cfg.model_copy(update={"block_size": block, "matcher_mode": mode}))


def stereo_bm(n: int, block: int, prefilter: int, cfg: StereoConfig) -> cv2.StereoBM:
    bm = cv2.StereoBM.create(numDisparities=n, blockSize=block)
    bm.setPreFilterType(prefilter)
    bm.setPreFilterSize(9)
    bm.setPreFilterCap(31)
    bm.setTextureThreshold(10)
    bm.setUniquenessRatio(cfg.uniqueness)
    bm.setSpeckleWindowSize(cfg.speckle_window)
    bm.setSpeckleRange(cfg.speckle_range)
    bm.setDisp12MaxDiff(-1)
    return bm


def checked_disparity(
    lg: np.ndarray, rg: np.ndarray, matcher: cv2.StereoMatcher, n: int, cfg: StereoConfig
) -> np.ndarray:
    """Left disparity (px, NaN unknown) left-right checked as stereo.match_depth checks it."""
    a = padded_match(matcher, lg, rg, n)
    b = padded_match(matcher, rg[:, ::-1], lg[:, ::-1], n)[:, ::-1]
    a[a <= 0] = np.nan
    b[b <= 0] = np.nan
    keep = consistent(a, b, cfg.lr_max_diff_px) & (a >= cfg.min_disparity_px)
    return np.where(keep, a, np.nan)


def to_depth(disparity: np.ndarray, fx: float, baseline_mm: float) -> np.ndarray:
    ok = np.isfinite(disparity) & (disparity > 0)
    depth = np.zeros(disparity.shape, np.float32)
    depth[ok] = fx * baseline_mm / disparity[ok]
    return depth


def median_refined(disparity: np.ndarray, k: int) -> np.ndarray:
    """Each known disparity replaced by its k x k median where that is within 1 px of it (a
    cheap sub-pixel smoothing that cannot fill a hole or cross an edge)."""
    filled = np.nan_to_num(disparity, nan=0.0).astype(np.float32)
    med = cv2.medianBlur(filled, k)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(disparity) & (med > 0) & (np.abs(med - disparity) < 1.0)
    out = disparity.copy()
    out[ok] = med[ok]
    return out


def ours(
    left: np.ndarray, right: np.ndarray, fx: float, baseline_mm: float, cfg: StereoConfig
) -> dict[str, np.ndarray]:
    return {"": match_depth(left, right, fx, baseline_mm, cfg)}


def sgbm_variant(mode: str, block: int, median: tuple[int, ...] = ()) -> Matcher:
    def run(
        left: np.ndarray, right: np.ndarray, fx: float, baseline_mm: float, cfg: StereoConfig
    ) -> dict[str, np.ndarray]:
        lg, rg = grey(left), grey(right)
        n = disparity_range(lg, rg, fx, baseline_mm, cfg)
        d = checked_disparity(lg, rg, sgbm(n, block, mode, cfg), n, cfg)
        out = {"": to_depth(d, fx, baseline_mm)}
        for k in median:
            out[f" +median{k}"] = to_depth(median_refined(d, k), fx, baseline_mm)
        return out

    return run


def bm_variant(prefilter: str, block: int) -> Matcher:
    def run(
        left: np.ndarray, right: np.ndarray, fx: float, baseline_mm: float, cfg: StereoConfig
    ) -> dict[str, np.ndarray]:
        lg, rg = grey(left), grey(right)
        n = disparity_range(lg, rg, fx, baseline_mm, cfg)
        d = checked_disparity(lg, rg, stereo_bm(n, block, PREFILTERS[prefilter], cfg), n, cfg)
        return {"": to_depth(d, fx, baseline_mm)}

    return run


def wls_variant(block: int, lam: float, sigma: float, confidences: list[float]) -> Matcher:
    """SGBM 3-way at `block` with its right matcher, WLS filtered (lambda, sigma colour): every
    pixel; those whose confidence reaches each threshold (0..255); those the raw matches'
    left-right check keeps."""

    def run(
        left: np.ndarray, right: np.ndarray, fx: float, baseline_mm: float, cfg: StereoConfig
    ) -> dict[str, np.ndarray]:
        lg, rg = grey(left), grey(right)
        n = disparity_range(lg, rg, fx, baseline_mm, cfg)
        left_m = sgbm(n, block, "3way", cfg)
        right_m = cv2.ximgproc.createRightMatcher(left_m)
        wls = cv2.ximgproc.createDisparityWLSFilter(left_m)
        wls.setLambda(lam)
        wls.setSigmaColor(sigma)
        # padded on the left only, as stereo.padded_match: columns padded on the right have no
        # match, and the filter would spread their made-up disparities into the image
        pad = [cv2.copyMakeBorder(im, 0, 0, n, 0, cv2.BORDER_REPLICATE) for im in (lg, rg)]
        raw_l = left_m.compute(pad[0], pad[1])
        raw_r = right_m.compute(pad[1], pad[0])
        filtered = wls.filter(raw_l, pad[0], disparity_map_right=raw_r)
        conf = np.asarray(wls.getConfidenceMap())[:, n:]
        d = filtered[:, n:].astype(np.float32) / SUBPIXEL
        d[d < cfg.min_disparity_px] = np.nan
        a = raw_l[:, n:].astype(np.float32) / SUBPIXEL
        a[a <= 0] = np.nan
        # the right view's disparities are negative; no match is (its minDisparity - 1) x 16
        raw_r = raw_r[:, n:]
        b = -raw_r.astype(np.float32) / SUBPIXEL
        b[(raw_r < right_m.getMinDisparity() * SUBPIXEL) | (b <= 0)] = np.nan
        lr = consistent(a, b, cfg.lr_max_diff_px)
        out = {" all": to_depth(d, fx, baseline_mm)}
        for c in confidences:
            out[f" conf>={c:g}"] = to_depth(np.where(conf >= c, d, np.nan), fx, baseline_mm)
        out[" lr-checked"] = to_depth(np.where(lr, d, np.nan), fx, baseline_mm)
        return out

    return run


def matchers(args: argparse.Namespace) -> dict[str, Matcher]:
    """Every matcher by its row name (a size is added to it)."""
    out: dict[str, Matcher] = {"ours": ours}
    for mode in MODES:
        for block in args.blocks:
            median = (3, 5) if (mode == "3way" and block == 5) else ()
            out[f"sgbm {mode} b{block}"] = sgbm_variant(mode, block, median)
    for prefilter in PREFILTERS:
        for block in args.bm_blocks:
            out[f"bm {prefilter} b{block}"] = bm_variant(prefilter, block)
    if hasattr(cv2, "ximgproc"):
        for block in args.wls_blocks:
            for lam in args.wls_lambda:
                out[f"wls 3way b{block} l{lam:g}"] = wls_variant(
                    block, lam, args.wls_sigma, args.wls_conf
                )
    else:
        print(
            f"WLS skipped: cv2 {cv2.__version__} ({cv2.__file__}) has no ximgproc "
            "(opencv-contrib); PYTHONPATH=DIR with opencv-contrib-python-headless there"
        )
    if args.only:
        out = {k: v for k, v in out.items() if re.search(args.only, k)}
    return out


# ------------------------------------------------------------------------------ the data


def load_pairs(path: Path, frames: int, every: int, check: bool) -> list[Pair]:
    """Up to `frames` pairs, every `every`-th frame, of an input with right views and truth;
    paired and mended as ingest does (the rig check on the working size's images)."""
    source = open_input(path)
    assert source.stereo is not None, f"{path}: no right views with a baseline"
    assert source.intrinsics is not None, f"{path}: no camera"
    truth = source.ground_truth()
    assert truth is not None, f"{path}: no depth truth"
    cam = source.intrinsics
    size = working_size(cam.width, cam.height, WORKING_MAX)
    lefts: dict[int, np.ndarray] = {}
    small: dict[int, np.ndarray] = {}
    for frame in source.frames():
        small[frame.source_index] = resize(frame.rgb, size)
        if len(lefts) < frames and frame.source_index % every == 0:
            lefts[frame.source_index] = frame.rgb
    rig = RigCheck()
    if check:
        sources = sorted(small)

        def right_small(s: int) -> np.ndarray | None:
            r = source.stereo.right(s) if s in small else None
            return None if r is None else resize(r, size)

        rig = check_rig(sources, small.__getitem__, right_small, 2, camera=cam.scaled(*size))
        print(f"{path.name}: {rig.said}")
    pairs = []
    for s, left in lefts.items():
        right = source.stereo.right(s + rig.frame_offset)
        depth = truth.depth(s)
        if right is None or depth is None:
            continue
        pairs.append(
            Pair(
                f"{path.name}/{s}",
                left,
                right,
                np.asarray(depth, np.float32),
                cam,
                source.stereo.baseline_mm,
                rig,
            )
        )
    return pairs


def at_size(pair: Pair, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, float]:
    """(left, right, fx) at `size`: resized as ingest resizes, the right one mended there."""
    cam = pair.camera.scaled(*size)
    left, right = resize(pair.left, size), resize(pair.right, size)
    s = size[0] / working_size(pair.camera.width, pair.camera.height, WORKING_MAX)[0]
    rig = pair.rig.model_copy(update={"row_shift_px": pair.rig.row_shift_px * s})
    return left, mended_right(right, rig, cam), cam.fx


def config_at(scale: float, lr: bool) -> StereoConfig:
    """StereoConfig() with its working-size pixel settings brought to a size `scale` x it (with
    `lr`, the left-right check's tolerance too)."""
    base = StereoConfig()
    if scale == 1.0:
        return base
    return StereoConfig(
        min_disparity_px=base.min_disparity_px * scale,
        speckle_window=int(round(base.speckle_window * scale * scale)),
        speckle_range=max(1, int(round(base.speckle_range * scale))),
        lr_max_diff_px=base.lr_max_diff_px * (scale if lr else 1.0),
    )


def size_of(word: str, cam: Camera) -> tuple[int, int]:
    if word == "working":
        return working_size(cam.width, cam.height, WORKING_MAX)
    if word == "source":
        return cam.width, cam.height
    return working_size(cam.width, cam.height, int(word))


# ------------------------------------------------------------------------------ the scores


def score(depth: np.ndarray, truth: np.ndarray, median_scale: bool) -> dict[str, float]:
    """AbsRel, coverage, good2, good5 and bias (median t / d) of one frame, at the truth's size."""
    if depth.shape != truth.shape:
        depth = cv2.resize(depth, truth.shape[::-1], interpolation=cv2.INTER_NEAREST)
    valid = truth > 0
    got = valid & (depth > 0)
    if not got.any():
        return {"absrel": np.nan, "coverage": 0.0, "good2": 0.0, "good5": 0.0, "bias": np.nan}
    d, t = depth[got].astype(np.float64), truth[got].astype(np.float64)
    bias = float(np.median(t / d))
    if median_scale:
        d = d * bias
    rel = np.abs(d - t) / t
    n = valid.sum()
    return {
        "absrel": float(rel.mean()),
        "coverage": float(got.sum() / n),
        "good2": float((rel < 0.02).sum() / n),
        "good5": float((rel < 0.05).sum() / n),
        "bias": bias,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", type=Path, nargs="+", help="inputs with right views and truth")
    ap.add_argument(
        "--sizes",
        nargs="+",
        default=["working", "source"],
        help="working | source | a longer side in px",
    )
    ap.add_argument("--frames", type=int, default=6, help="pairs per case")
    ap.add_argument("--every", type=int, default=1, help="take every n-th frame")
    ap.add_argument(
        "--scale",
        choices=["none", "median"],
        default="none",
        help="median: each frame's depth scaled by its median t / d first",
    )
    ap.add_argument(
        "--scale-lr",
        action="store_true",
        help="at another size, scale the left-right check's tolerance too (else 1 px there)",
    )
    ap.add_argument("--no-check", action="store_true", help="no rig check (pair as named)")
    ap.add_argument("--only", default="", help="regex on the matcher names")
    ap.add_argument("--blocks", type=int, nargs="+", default=[3, 5, 7])
    ap.add_argument("--bm-blocks", type=int, nargs="+", default=[9, 15])
    ap.add_argument("--wls-blocks", type=int, nargs="+", default=[5])
    ap.add_argument("--wls-lambda", type=float, nargs="+", default=[8000.0])
    ap.add_argument("--wls-sigma", type=float, default=1.5)
    ap.add_argument("--wls-conf", type=float, nargs="+", default=[128.0, 255.0])
    ap.add_argument("--repeat", type=int, default=1, help="time each match this many times")
    ap.add_argument("--csv", type=Path, help="write every frame's scores here")
    args = ap.parse_args()
    cv2.setNumThreads(1)

    pairs = [
        p
        for case in args.cases
        for p in load_pairs(case, args.frames, args.every, not args.no_check)
    ]
    print(f"{len(pairs)} pairs from {len(args.cases)} cases; cv2 {cv2.__version__}")
    table = []
    per_frame = []
    for name, run in matchers(args).items():
        for word in args.sizes:
            rows: dict[str, list[dict[str, float]]] = {}
            ms = []
            for pair in pairs:
                work = size_of("working", pair.camera)
                size = size_of(word, pair.camera)
                scale = size[0] / work[0]
                cfg = StereoConfig() if name == "ours" else config_at(scale, args.scale_lr)
                left, right, fx = at_size(pair, size)
                truth = cv2.resize(pair.truth, work, interpolation=cv2.INTER_NEAREST)
                took = []
                for _ in range(args.repeat):  # the fastest of a few: another job may share the CPU
                    t0 = time.perf_counter()
                    depths = run(left, right, fx, pair.baseline_mm, cfg)
                    took.append((time.perf_counter() - t0) * 1e3)
                ms.append(min(took))
                for suffix, depth in depths.items():
                    s = score(depth, truth, args.scale == "median")
                    rows.setdefault(suffix, []).append(s)
                    per_frame.append(
                        {"matcher": name + suffix, "size": word, "pair": pair.name, **s}
                    )
            label = (
                f"{word} {size[0]}x{size[1]}"
                if word in ("working", "source")
                else (f"{size[0]}x{size[1]}")
            )
            for suffix, scores in rows.items():
                mean = {k: float(np.nanmean([s[k] for s in scores])) for k in scores[0]}
                row = (
                    name + suffix + (", default cfg" if name == "ours" and scale != 1 else ""),
                    label,
                    mean,
                    float(np.mean(ms)),
                )
                table.append(row)
                print(
                    f"{row[0]:28s} {row[1]:18s} AbsRel {mean['absrel']:.4f}  coverage "
                    f"{mean['coverage']:.3f}  good2 {mean['good2']:.3f}  good5 "
                    f"{mean['good5']:.3f}  bias "
                    f"{mean['bias']:.3f}  {row[3]:7.0f} ms",
                    flush=True,
                )
    print("\n| matcher | size | AbsRel | coverage | good2 | good5 | bias | ms/pair |")
    print("|---|---|---|---|---|---|---|---|")
    for name, label, m, t in table:
        print(
            f"| {name} | {label} | {m['absrel']:.4f} | {m['coverage']:.3f} | "
            f"{m['good2']:.3f} | {m['good5']:.3f} | {m['bias']:.3f} | {t:.0f} |"
        )
    if args.csv:
        with args.csv.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(per_frame[0]))
            w.writeheader()
            w.writerows(per_frame)


if __name__ == "__main__":
    main()
