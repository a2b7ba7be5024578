"""The nerf stage's evaluation after training: the held-out frames rendered and scored beside
their neighbours' average, a few training frames rendered for the fit and its word (fit.py), and
the figures (heldout.png, heldout_pairs.jpg, loss.png)."""

from __future__ import annotations

import textwrap
import time
from pathlib import Path

import numpy as np

from endopipe.stages.camera import lens_valid_mask
from endopipe.stages.io.ground_truth import depth_of_frame
from endopipe.stages.metrics.baselines import neighbour_guesses
from endopipe.stages.metrics.depth import affine_sequence_metrics, sequence_protocol
from endopipe.stages.metrics.exposure import exposure_matched
from endopipe.stages.nerf import losses
from endopipe.stages.nerf.config import NerfConfig
from endopipe.stages.nerf.files import HELDOUT_PAIRS_FILE, HELDOUT_RGB_DIR
from endopipe.stages.nerf.fit import fit_verdict
from endopipe.stages.nerf.metrics_file import NerfMetrics
from endopipe.stages.nerf.render import render_image
from endopipe.stages.poses.view import PosesView


def evaluate(
    model, prior, ingest, k, c2w, ids, held_ids, train_ids, cfg: NerfConfig, ctx, rests_on: str
) -> NerfMetrics:
    """Render the held-out frames (PSNR on usable pixels, depth metrics against ground truth)
    and a few training frames (the fit), beside the neighbour average of the held-out ones.
    A field with an exposure a frame has each held-out render's exposure fitted to the frame
    (metrics/exposure.py), the neighbour average too; the PSNR with the exposure its trained
    neighbours interpolate is kept beside."""
    held = held_ids[: cfg.train.eval_frames] if cfg.train.eval_frames else held_ids
    gt = ingest.ground_truth_for_scores(ctx.log)
    fov = ingest.fov()
    lens_valid = lens_valid_mask(k)
    pos = {i: p for p, i in enumerate(ids)}
    fits_exposure = model.cfg.shading.exposure is True

    def usable(i: int) -> np.ndarray:
        return (ingest.mask(i) > 127) & lens_valid

    def scored(i: int, rgb: np.ndarray) -> tuple[np.ndarray, float]:
        img = ingest.image(i).astype(np.float32) / 255.0
        m = usable(i)
        return img, float(((rgb - img) ** 2).mean(-1)[m].mean()) if m.any() else np.nan

    preds, gts, fovs, scored_ids, mses, times, previews, pairs = [], [], [], [], [], [], [], []
    interpolated = []  # a fitted exposure's MSE before the fit
    (ctx.out / HELDOUT_RGB_DIR).mkdir(exist_ok=True)
    for i in held:
        t0 = time.perf_counter()
        with model.at_frame(pos[i]):  # a dynamic field: at the frame's own time
            out = render_image(model, prior, k, c2w[pos[i]], frame=pos[i])
        times.append(time.perf_counter() - t0)
        img, mse = scored(i, out["rgb"])
        if fits_exposure:
            interpolated.append(mse)
            out["rgb"] = exposure_matched(out["rgb"], img, usable(i))[0]
            mse = scored(i, out["rgb"])[1]
        save_rgb16(ctx.out / HELDOUT_RGB_DIR / f"{i:06d}.png", out["rgb"])  # the depth stage's
        mses.append(mse)
        pairs.append((i, img, out["rgb"], losses.psnr(mse)))
        g = depth_of_frame(gt, ingest.frame(i))
        if g is not None and g.shape != out["depth"].shape:
            import cv2

            g = cv2.resize(g, out["depth"].shape[::-1], interpolation=cv2.INTER_NEAREST)
        previews.append((img, out, g))
        if g is not None:
            preds.append(out["depth"])
            gts.append(g)
            fovs.append(fov > 127 if fov is not None else None)
            scored_ids.append(i)
    result: dict = {
        "heldout": held,
        "render_rgb_ms": round(1000 * float(np.median(times)), 1) if times else None,
    }
    if mses:
        result["psnr"] = round(float(np.nanmean([losses.psnr(m) for m in mses])), 3)
        result["neighbour_psnr"] = neighbour_psnr(ingest, held, set(held_ids), fits_exposure)
        result["exposure_fitted"] = fits_exposure
        if interpolated:
            psnrs = [losses.psnr(m) for m in interpolated]
            result["psnr_exposure_interpolated"] = round(float(np.nanmean(psnrs)), 3)
    fitted = spread_out(train_ids, cfg.train.fit_frames)
    fit = []
    for i in fitted:
        with model.at_frame(pos[i]):
            rgb = render_image(model, prior, k, c2w[pos[i]], frame=pos[i], colour=True)["rgb"]
        fit.append(losses.psnr(scored(i, rgb)[1]))
    if fit:
        result["train_psnr"] = round(float(np.nanmean(fit)), 3)
        result["fit_frames"] = fitted
    verdict = fit_verdict(
        result.get("train_psnr"), result.get("psnr"), result.get("neighbour_psnr"), rests_on
    )
    result["fit"] = verdict.word
    result["fit_said"] = verdict.said
    poses = ctx.input(PosesView)
    # the truth's own protocols: an affine proxy of depth (C3VD's panel) only up to scale and
    # shift; the depth as it is only where the poses are metric
    sequence = sequence_protocol(gt, poses.metric)
    relative = sequence is affine_sequence_metrics
    if preds:
        blocks = sequence(preds, gts, fovs, scored_ids)
        names = ("median_scaled", "sequence_scaled", "unscaled", "affine_invariant")
        result["depth"] = {k: blocks[k] for k in names if k in blocks}
        result["depth_frames"] = len(preds)
    if previews:
        truth_units = "relative" if relative else getattr(gt, "units", "")
        write_preview(
            ctx.out / "heldout.png",
            previews[:4],
            poses.file.units,
            poses.metric and not relative,
            truth_units,
        )
        write_pairs(ctx.out / HELDOUT_PAIRS_FILE, pairs)
    return NerfMetrics.model_validate(result)


def spread_out(ids: list[int], n: int) -> list[int]:
    """`n` of `ids` evenly spread over them (all when fewer; none for n = 0)."""
    if n <= 0 or not ids:
        return []
    if len(ids) <= n:
        return list(ids)
    return [ids[int(round(x))] for x in np.linspace(0, len(ids) - 1, n)]


def neighbour_psnr(
    ingest, held: list[int], skip: set[int], fit_exposure: bool = False
) -> float | None:
    """The held-out frames' PSNR when each is guessed as the average of its nearest trained
    neighbours before and after (on the pixels the field's PSNR counts), its exposure fitted to
    the frame as the field's render's is (`fit_exposure`); None without any."""
    order = [f.index for f in ingest.frames]
    vals = [
        losses.psnr(float(((guess - frame) ** 2).mean(-1)[m].mean()))
        for frame, guess, m in neighbour_guesses(
            lambda i: ingest.image(i).astype(np.float32) / 255.0,
            lambda i: ingest.mask(i) > 127,
            order,
            held,
            skip,
            fit_exposure,
        )
    ]
    return round(float(np.mean(vals)), 3) if vals else None


def write_pairs(path: Path, pairs: list[tuple[int, np.ndarray, np.ndarray, float]]) -> None:
    """heldout_pairs.jpg: every held-out frame beside the field's render of it, with its PSNR
    (heldout.png shows four, with their depth)."""
    from matplotlib.figure import Figure

    h, w = pairs[0][1].shape[:2]
    cols = 4  # pairs per row
    rows = (len(pairs) + cols - 1) // cols
    tile = 1.6
    fig = Figure(figsize=(2 * cols * tile, rows * tile * h / w + 0.3), dpi=100)
    for n, (i, img, rgb, psnr) in enumerate(pairs):
        for c, (pic, label) in enumerate(((img, f"frame {i}"), (rgb, f"render {psnr:.1f} dB"))):
            ax = fig.add_subplot(rows, 2 * cols, n * 2 + c + 1)
            ax.imshow(np.clip(pic, 0, 1))
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(label, fontsize=6, pad=2)
    fig.tight_layout(pad=0.3)
    fig.savefig(path, facecolor="white", pil_kwargs={"quality": 85})


#: Depth is drawn with one colour map everywhere (this grid, 05_depth/preview.mp4, the report).
DEPTH_CMAP = "turbo"


def write_preview(
    path: Path, items, units: str = "", metric: bool = True, truth_units: str = ""
) -> None:
    """heldout.png: the held-out grid of `heldout_figure`."""
    heldout_figure(items, units, metric, truth_units).savefig(path, facecolor="white")


def heldout_figure(items, units: str = "", metric: bool = True, truth_units: str = ""):
    """Held-out frames, a row each: image | rendering | rendered depth | ground-truth depth,
    with column titles and a colour bar per depth panel. With metric poses (and a metric truth)
    the rendered depth shares the ground truth's colour scale; otherwise each has its own.
    `units` are the rendered depth's (the poses'), `truth_units` the truth's ("relative": an
    affine proxy of depth). `items`: (image, rendering {rgb, depth}, ground-truth depth or
    None) per frame."""
    from matplotlib.figure import Figure

    h, w = items[0][1]["depth"].shape[:2]
    titles = ["held-out image", "NeRF rendering", f"rendered depth ({units or 'scene units'})"]
    has_gt = any(g is not None for _, _, g in items)
    if has_gt:
        titles.append(f"ground-truth depth ({truth_units or units or 'GT units'})")
    ncols, tile = len(titles), 2.6
    fig = Figure(figsize=(tile * ncols + 0.6, len(items) * tile * h / w + 0.6), dpi=100)
    for r, (img, out, gt) in enumerate(items):
        axes = [fig.add_subplot(len(items), ncols, r * ncols + c + 1) for c in range(ncols)]
        axes[0].imshow(np.clip(img, 0, 1))
        axes[1].imshow(np.clip(out["rgb"], 0, 1))
        depth_panels = [(axes[2], out["depth"])] + ([(axes[3], gt)] if gt is not None else [])
        shared = _depth_range(gt) if gt is not None and metric else None
        if has_gt and gt is None:
            axes[3].text(0.5, 0.5, "no ground truth", ha="center", va="center", color="0.5")
        for ax, z in depth_panels:
            lo, hi = shared or _depth_range(z)
            im = ax.imshow(np.ma.masked_where(z <= 0, z), cmap=DEPTH_CMAP, vmin=lo, vmax=hi)
            fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02).ax.tick_params(labelsize=6)
        for c, ax in enumerate(axes):
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(textwrap.fill(titles[c], 32), fontsize=8)  # a truth's long units
    fig.tight_layout()
    return fig


def _depth_range(z: np.ndarray) -> tuple[float, float]:
    """The 2nd to 98th percentile of the valid depth: the colour scale of a depth panel."""
    valid = z[(z > 0) & np.isfinite(z)]
    lo, hi = np.percentile(valid, [2, 98]) if valid.size else (0.0, 1.0)
    return float(lo), float(hi if hi > lo else lo + 1e-6)


def plot_log(rows: list[dict], path: Path) -> None:
    """loss.png: the curves of `loss_figure` (nothing without a logged step)."""
    if rows:
        loss_figure(rows).savefig(path, facecolor="white")


def loss_figure(rows: list[dict]):
    """Losses (log scale; the legend beside the plot, never over a curve) and training PSNR."""
    from matplotlib.figure import Figure

    steps = [r["step"] for r in rows]
    fig = Figure(figsize=(11, 3.6), dpi=90)
    loss_ax, psnr_ax = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    for key in ("loss", "photo", "prior", "smooth", "geo", "sparse", "stereo", "depth_prior"):
        vals = [r.get(key) for r in rows]
        if any(v is not None for v in vals):
            loss_ax.plot(steps, [np.nan if v is None else v for v in vals], label=key)
    loss_ax.set_yscale("log")
    loss_ax.set_xlabel("step")
    loss_ax.set_title("training losses (log scale)", fontsize=10)
    loss_ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
    psnr_ax.plot(steps, [r["psnr"] for r in rows])
    psnr_ax.set_xlabel("step")
    psnr_ax.set_ylabel("train PSNR (dB)")
    psnr_ax.set_title("training PSNR (batch rays)", fontsize=10)
    fig.tight_layout()
    return fig


def save_rgb16(path: Path, rgb: np.ndarray) -> None:
    """An (H, W, 3) image in [0, 1] as a lossless 16-bit PNG (PSNR is unchanged by it)."""
    import cv2

    img = np.clip(np.round(np.asarray(rgb, np.float64) * 65535.0), 0, 65535).astype(np.uint16)
    cv2.imwrite(str(path), img[..., ::-1])
