"""nerf: a NeRF of the lumen regularised by the anatomical prior (seed §3), fast on a CPU.

Trains on the registered frames except every 8th (index % 8 == 0, held out and evaluated), with
ray bounds and L_prior from the centerline stage's tube prior. Writes model.pt (see render.py to
use it), train_log.csv, loss.png, heldout.png and metrics.json; resumes from checkpoint.pt
after a kill (the stage is resumable, its temporary folder survives).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch

from endopipe.pipeline.errors import EndopipeError, InputError
from endopipe.pipeline.stage import Stage, StageContext, Summary, write_json
from endopipe.stages.camera import Camera, pixel_rays
from endopipe.stages.io.ground_truth import depth_of_frame
from endopipe.stages.metrics.depth import depth_sequence_metrics
from endopipe.stages.nerf import losses
from endopipe.stages.nerf.bounds import PriorBounds
from endopipe.stages.nerf.config import NerfConfig
from endopipe.stages.nerf.data import FrameSet, holdout_split
from endopipe.stages.nerf.render import MODEL_FILE, render_image, save_model
from endopipe.stages.nerf.scene import SceneBox
from endopipe.stages.nerf.sparse_depth import sparse_depth_targets
from endopipe.stages.nerf.train import CHECKPOINT, Trainer, auto_threads, pick_device
from endopipe.stages.nerf.view import NerfView


def load_prior(centerline) -> object:
    """The LumenPrior of the centerline stage (its folder, or a view with a folder)."""
    from endopipe.stages.centerline.prior import LumenPrior

    if hasattr(centerline, "prior") and not callable(centerline.prior):
        return centerline.prior
    folder = Path(getattr(centerline, "folder", centerline))
    path = folder / "prior.npz" if folder.is_dir() else folder
    if not path.is_file():
        raise EndopipeError(f"no lumen prior at {path}; re-run the centerline stage")
    return LumenPrior.load(path)


def fit_box(c2w: list[np.ndarray], camera: Camera, hw: tuple[int, int], prior, cfg) -> SceneBox:
    """Scene box around what the cameras can see inside the prior's (inflated) lumen."""
    centres = np.array([c[:3, 3] for c in c2w])
    box0 = SceneBox.fit(centres, float(prior.typical_radius), centres)
    box0.lo, box0.hi = np.full(3, -1.0), np.full(3, 1.0)
    pb = PriorBounds(prior, box0, cfg)
    h, w = hw
    vv, uu = np.meshgrid(np.linspace(0, h - 1, 12), np.linspace(0, w - 1, 16), indexing="ij")
    u = torch.tensor(uu.ravel(), dtype=torch.float32)
    v = torch.tensor(vv.ravel(), dtype=torch.float32)
    pts = []
    for c in c2w:
        cs = torch.tensor(box0.c2w_to_scene(c), dtype=torch.float32)
        o, d = pixel_rays(camera, cs, u, v)
        _, far, _ = pb.bounds(o, d, cfg.sampling.bounds_margin, wall=True)
        pts.append(box0.scene_to_world_np((o + far[:, None] * d).numpy()))
    f = cfg.field
    return SceneBox.fit(
        centres,
        float(prior.typical_radius),
        np.concatenate(pts),
        core_pad=f.warp_core_pad if f.warp else None,
        soft=f.warp_soft,
    )


def load_sparse_depth(
    ingest, poses, positions: dict[int, int], box, cfg: NerfConfig, device: torch.device
):
    """SfM-point depth targets of the training frames (None when the poses have no tracks).
    Pixels are rescaled when the poses' camera has another resolution than the frames."""
    obs = poses.observations(ingest.index_by_name())
    k = poses.intrinsics
    if obs is not None and (k.width, k.height) != (ingest.width, ingest.height):
        scale = np.array([ingest.width / k.width, ingest.height / k.height])
        obs.uv = (obs.uv + 0.5) * scale - 0.5
    lc = cfg.loss
    return sparse_depth_targets(
        obs,
        positions,
        poses.c2w,
        box.scale,
        (ingest.height, ingest.width),
        lc.sparse_min_track,
        lc.sparse_max_error,
        device,
    )


def build_frames(ingest, poses, device: torch.device):
    """Registered frames (endopipe order): images in [0, 1], usable masks, world c2w."""
    ids = [i for i in poses.registered if i < len(ingest.frames)]
    if len(ids) < 2:
        raise EndopipeError(f"nerf needs at least 2 registered frames, got {len(ids)}")
    k = poses.intrinsics
    if (k.width, k.height) != (ingest.width, ingest.height):
        k = k.scaled(ingest.width, ingest.height)
    images = np.stack([ingest.image(i) for i in ids]).astype(np.float32) / 255.0
    masks = np.stack([ingest.mask(i) > 127 for i in ids])
    c2w = [poses.c2w[i] for i in ids]
    return ids, k, images, masks, c2w


class NerfSummary(Summary):
    steps: int
    train_frames: int
    heldout_frames: int
    train_s: float
    rays_per_s: float
    render_ms: float | None = None
    heldout_psnr: float | None = None
    depth: dict | None = None
    resumed_from: int = 0
    device: str = "cpu"
    threads: int = 1


class Nerf(Stage):
    """NeRF with near-light shading and the lumen prior (TensoRF VM grid by default)."""

    name = "nerf"
    needs = ("ingest", "poses", "centerline")
    version = 1
    Config = NerfConfig
    resumable = True

    @classmethod
    def view(cls, folder: Path) -> NerfView:
        return NerfView(folder)

    def run(self, ctx: StageContext) -> NerfSummary:
        cfg: NerfConfig = ctx.config  # type: ignore[assignment]
        threads = torch.get_num_threads()
        torch.set_num_threads(cfg.train.threads or auto_threads())
        try:
            return self._run(ctx, cfg)
        finally:
            torch.set_num_threads(threads)

    def _run(self, ctx: StageContext, cfg: NerfConfig) -> NerfSummary:
        device = pick_device(cfg.train.device)
        ingest, poses = ctx.input("ingest"), ctx.input("poses")
        prior = load_prior(ctx.input("centerline"))
        ids, k, images, masks, c2w = build_frames(ingest, poses, device)
        box = fit_box(c2w, k, images.shape[1:3], prior, cfg)
        frames = FrameSet(
            images, masks, np.stack([box.c2w_to_scene(c) for c in c2w]), k, ids, device
        )
        train_ids, held_ids = holdout_split(ids, cfg.train.holdout_every)
        pos = {i: p for p, i in enumerate(ids)}
        sparse = None
        if cfg.loss.sparse_weight > 0:
            train_pos = {i: pos[i] for i in train_ids}
            sparse = load_sparse_depth(ingest, poses, train_pos, box, cfg, device)
            ctx.log(f"sparse depth: {len(sparse) if sparse else 0} SfM-point rays")
        trainer = Trainer(
            cfg, frames, [pos[i] for i in train_ids], prior, box, ctx.out, ctx.log, sparse
        )
        resumed = trainer.try_resume()
        start = trainer.step_i
        if resumed:
            ctx.log(f"resuming from checkpoint at step {start}")
        with ctx.progress("nerf", total=cfg.train.steps) as advance:
            trainer.fit(advance)
        trainer.save_checkpoint()  # a crash while evaluating resumes here, not steps back
        trainer.write_log(ctx.out / "train_log.csv")
        plot_log(trainer.rows, ctx.out / "loss.png")
        save_model(
            ctx.out / MODEL_FILE,
            trainer.model,
            {"frame_ids": ids, "train": train_ids, "heldout": held_ids, "units": poses.file.units},
        )
        model = trainer.model.eval()
        rays_per_s = cfg.train.batch_rays * trainer.step_i / max(trainer.elapsed, 1e-9)
        evaluation = evaluate(model, prior, ingest, k, c2w, ids, held_ids, cfg, ctx)
        (ctx.out / CHECKPOINT).unlink(missing_ok=True)
        write_json(ctx.out / "metrics.json", evaluation)
        return NerfSummary(
            steps=trainer.step_i,
            train_frames=len(train_ids),
            heldout_frames=len(held_ids),
            train_s=round(trainer.elapsed, 2),
            rays_per_s=round(rays_per_s, 1),
            render_ms=evaluation.get("render_ms"),
            heldout_psnr=evaluation.get("psnr"),
            depth=evaluation.get("depth"),
            resumed_from=start,
            device=str(device),
            threads=torch.get_num_threads(),
        )


def evaluate(model, prior, ingest, k, c2w, ids, held_ids, cfg: NerfConfig, ctx) -> dict:
    """Render the held-out frames: PSNR on usable pixels, depth metrics against ground truth."""
    held = held_ids[: cfg.train.eval_frames] if cfg.train.eval_frames else held_ids
    try:
        gt = ingest.ground_truth()
    except InputError as e:
        ctx.log(f"ground truth ignored: {e}")  # it only evaluates the NeRF: not fatal here
        gt = None
    fov = ingest.fov()
    pos = {i: p for p, i in enumerate(ids)}
    preds, gts, fovs, mses, times, previews = [], [], [], [], [], []
    for i in held:
        t0 = time.perf_counter()
        out = render_image(model, prior, k, c2w[pos[i]])
        times.append(time.perf_counter() - t0)
        img = ingest.image(i).astype(np.float32) / 255.0
        m = ingest.mask(i) > 127
        mses.append(float(((out["rgb"] - img) ** 2).mean(-1)[m].mean()) if m.any() else np.nan)
        previews.append((img, out))
        g = depth_of_frame(gt, ingest.frame(i))
        if g is not None:
            if g.shape != out["depth"].shape:
                import cv2

                g = cv2.resize(g, out["depth"].shape[::-1], interpolation=cv2.INTER_NEAREST)
            preds.append(out["depth"])
            gts.append(g)
            fovs.append(fov > 127 if fov is not None else None)
    depth_ms = []
    for i in held[:3]:  # what the depth stage pays per frame: depth and opacity only
        t0 = time.perf_counter()
        render_image(model, prior, k, c2w[pos[i]], colour=False)
        depth_ms.append(1000 * (time.perf_counter() - t0))
    result: dict = {
        "heldout": held,
        "render_ms": round(float(np.median(depth_ms)), 1) if depth_ms else None,
        "render_rgb_ms": round(1000 * float(np.median(times)), 1) if times else None,
    }
    if mses:
        result["psnr"] = round(float(np.nanmean([losses.psnr(m) for m in mses])), 3)
    if preds:
        metrics = depth_sequence_metrics(preds, gts, fovs, unscaled=True)
        result["depth"] = {k: metrics[k] for k in ("median_scaled", "sequence_scaled", "unscaled")}
        result["depth_frames"] = len(preds)
    if previews:
        write_preview(ctx.out / "heldout.png", previews[:4], gts[:4] if gts else None)
    return result


def write_preview(path: Path, items, gts) -> None:
    """Rows of held-out frames: image, rendering, rendered depth, ground-truth depth."""
    import cv2

    rows = []
    for n, (img, out) in enumerate(items):
        d = out["depth"]
        ref = gts[n] if gts else d
        lo, hi = np.percentile(ref[ref > 0], [1, 99]) if (ref > 0).any() else (0.0, 1.0)

        def colour(z, lo=lo, hi=hi):
            x = np.clip(
                (np.log(np.maximum(z, 1e-6)) - np.log(lo)) / (np.log(hi) - np.log(lo)), 0, 1
            )
            c = cv2.applyColorMap((x * 255).astype(np.uint8), cv2.COLORMAP_TURBO)[:, :, ::-1]
            return np.where((z > 0)[..., None], c, 0).astype(np.uint8)

        tiles = [(img * 255).astype(np.uint8), (out["rgb"] * 255).astype(np.uint8), colour(d)]
        if gts:
            tiles.append(colour(gts[n]))
        rows.append(np.concatenate(tiles, 1))
    cv2.imwrite(str(path), cv2.cvtColor(np.concatenate(rows, 0), cv2.COLOR_RGB2BGR))


def plot_log(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not rows:
        return
    steps = [r["step"] for r in rows]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for key in ("loss", "photo", "prior", "smooth", "geo", "sparse"):
        vals = [r.get(key) for r in rows]
        if any(v is not None for v in vals):
            axes[0].plot(steps, [np.nan if v is None else v for v in vals], label=key)
    axes[0].set_yscale("log")
    axes[0].set_xlabel("step")
    axes[0].legend()
    axes[1].plot(steps, [r["psnr"] for r in rows])
    axes[1].set_xlabel("step")
    axes[1].set_ylabel("train PSNR (dB)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def describe_config() -> str:
    return json.dumps(NerfConfig().model_dump(mode="json"), indent=1)
