"""depth: a z-depth map per registered frame from the trained field, evaluated when GT exists."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from pydantic import Field

from endopipe.pipeline.stage import Stage, StageConfig, StageContext, Summary, write_json
from endopipe.stages.io.ground_truth import GroundTruthSource, open_ground_truth
from endopipe.stages.io.video_writer import write_mp4
from endopipe.stages.metrics.depth import (
    affine_fit,
    affine_sequence_metrics,
    depth_sequence_metrics,
    image_metrics,
)

PNG_MAX = 65535


class DepthConfig(StageConfig):
    renderer: Literal["baked", "field"] = Field(
        "baked",
        description="baked: ray-cast an iso-surface baked once from the field's density (fast); "
        "field: volume-render the trained field at every sample (exact expected depth, slow).",
    )
    bake_voxels_per_radius: int = Field(
        24, ge=4, le=256, description="Baked surface: grid nodes per lumen radius."
    )
    bake_density_level: float | None = Field(
        None,
        gt=0,
        description="Baked surface: density iso-level, per lumen radius (None: calibrated so "
        "that the baked surface passes through the field's rendered surface).",
    )
    preview: bool = Field(True, description="Write preview.mp4 (RGB | depth | error).")
    preview_fps: int = Field(10, ge=1, description="Frame rate of preview.mp4.")
    colour: bool = Field(
        True, description="Render colour too (needed for PSNR/SSIM on held-out frames)."
    )


class DepthSummary(Summary):
    frames: int
    units: str
    png_scale: float
    ms_per_frame: float
    bake_s: float
    renderer: str
    gt_kind: str | None = None
    median_scaled: dict | None = None
    sequence_scaled: dict | None = None
    affine_invariant: dict | None = None
    heldout_psnr: float | None = None
    heldout_ssim: float | None = None


class DepthView:
    """Typed access to 05_depth: depth maps by endopipe frame index."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.indices = sorted(int(p.stem) for p in (folder / "depth").glob("*.npy"))

    def depth(self, index: int) -> np.ndarray:
        return np.load(self.folder / "depth" / f"{index:06d}.npy")

    def opacity(self, index: int) -> np.ndarray | None:
        path = self.folder / "opacity" / f"{index:06d}.npy"
        return np.load(path) if path.is_file() else None


class Depth(Stage):
    """Render every registered frame's depth (z, world units) and opacity; evaluate against GT."""

    name = "depth"
    needs = ("ingest", "poses", "centerline", "nerf")
    version = 1
    Config = DepthConfig

    @classmethod
    def view(cls, folder: Path) -> DepthView:
        return DepthView(folder)

    def run(self, ctx: StageContext) -> DepthSummary:
        from endopipe.stages.nerf.render import load_model
        from endopipe.stages.nerf.stage import load_prior

        cfg: DepthConfig = ctx.config  # type: ignore[assignment]
        ingest, poses = ctx.input("ingest"), ctx.input("poses")
        model = load_model(ctx.input_dir("nerf"))
        prior = load_prior(ctx.input("centerline"))
        k = poses.intrinsics
        if (k.width, k.height) != (ingest.width, ingest.height):
            k = k.scaled(ingest.width, ingest.height)
        t_bake = time.perf_counter()
        renderer = make_renderer(cfg, model, prior, [poses.c2w[i] for i in poses.registered], k)
        bake_s = time.perf_counter() - t_bake
        heldout = set(getattr(model, "meta", {}).get("heldout", []))
        for sub in ("depth", "opacity"):
            (ctx.out / sub).mkdir()
        depths, rgbs, times = {}, {}, []
        with ctx.progress("depth", total=len(poses.registered)) as advance:
            for i in poses.registered:
                t0 = time.perf_counter()
                out = renderer(k, poses.c2w[i], i, colour=cfg.colour and i in heldout)
                times.append(time.perf_counter() - t0)
                depths[i] = out["depth"].astype(np.float32)
                np.save(ctx.out / "depth" / f"{i:06d}.npy", depths[i])
                np.save(ctx.out / "opacity" / f"{i:06d}.npy", out["opacity"].astype(np.float32))
                if "rgb" in out:
                    rgbs[i] = out["rgb"]
                advance(info=f"{1000 * times[-1]:.0f} ms/frame")
        png_scale = write_depth_pngs(ctx.out / "depth", depths)
        gt = open_ground_truth(Path(ctx.case.gt_dir)) if ctx.case.gt_dir else None
        gt_depths = ground_truth_depths(gt, ingest, list(depths))
        metrics = evaluate(gt, ingest, depths, gt_depths, rgbs)
        write_json(ctx.out / "metrics.json", metrics)
        if cfg.preview:
            affine = metrics.get("gt_kind") == "relative"
            write_preview(
                ctx.out / "preview.mp4", ingest, depths, gt_depths, cfg.preview_fps, affine
            )
        ms = 1000 * float(np.median(times[1:] if len(times) > 1 else times))
        ctx.log(
            f"{len(depths)} depth maps, {ms:.0f} ms per frame ({cfg.renderer}; "
            f"baking {bake_s:.1f} s)"
        )
        return DepthSummary(
            frames=len(depths),
            units=poses.file.units,
            png_scale=png_scale,
            ms_per_frame=ms,
            bake_s=bake_s,
            renderer=cfg.renderer,
            gt_kind=metrics.get("gt_kind"),
            median_scaled=metrics.get("median_scaled"),
            sequence_scaled=metrics.get("sequence_scaled"),
            affine_invariant=metrics.get("affine_invariant"),
            heldout_psnr=metrics.get("heldout_psnr"),
            heldout_ssim=metrics.get("heldout_ssim"),
        )


def make_renderer(cfg: DepthConfig, model, prior, c2ws: list[np.ndarray], k):
    """A function (intrinsics, c2w, frame, colour) -> {depth, opacity[, rgb]}."""
    from endopipe.stages.nerf.render import render_image

    if cfg.renderer == "field":
        return lambda k, c2w, i, colour: render_image(model, prior, k, c2w, colour=colour)
    from endopipe.stages.nerf.baked import BakedSurface

    baked = BakedSurface.bake(
        model, prior, c2ws, k, cfg.bake_voxels_per_radius, cfg.bake_density_level
    )

    def render(k, c2w, i, colour):
        out = baked.render_depth(k, c2w)
        if colour:  # colour needs the albedo field: render it exactly, only for held-out frames
            out["rgb"] = render_image(model, prior, k, c2w, colour=True)["rgb"]
        return out

    return render


def write_depth_pngs(folder: Path, depths: dict[int, np.ndarray]) -> float:
    """16-bit PNGs with one scale for the sequence (world units per count), in the manifest."""
    top = max(float(d.max()) for d in depths.values()) if depths else 1.0
    scale = max(top, 1e-6) / PNG_MAX
    for i, d in depths.items():
        png = np.clip(np.round(d / scale), 0, PNG_MAX).astype(np.uint16)
        cv2.imwrite(str(folder / f"{i:06d}.png"), png)
    return scale


def ground_truth_depths(
    gt: GroundTruthSource | None, ingest, indices: list[int]
) -> dict[int, np.ndarray]:
    """GT depth per frame at the working resolution (nearest-neighbour, no blending of edges)."""
    if gt is None:
        return {}
    out = {}
    for i in indices:
        d = gt.depth(ingest.frames[i].source_index)
        if d is None:
            continue
        if d.shape != (ingest.height, ingest.width):
            d = cv2.resize(d, (ingest.width, ingest.height), interpolation=cv2.INTER_NEAREST)
        out[i] = d.astype(np.float32)
    return out


def evaluate(
    gt: GroundTruthSource | None,
    ingest,
    depths: dict[int, np.ndarray],
    gt_depths: dict[int, np.ndarray],
    rgbs: dict[int, np.ndarray],
) -> dict:
    """DESIGN §6: both depth protocols per frame and mean; PSNR / SSIM on held-out frames."""
    metrics: dict = {}
    fov = ingest.fov() > 0
    if gt_depths:
        ids = sorted(gt_depths)
        kind = getattr(gt, "kind", "exact")
        # A relative ground truth (an affine proxy of depth) supports no metric protocol.
        sequence = affine_sequence_metrics if kind == "relative" else depth_sequence_metrics
        metrics.update(
            sequence([depths[i] for i in ids], [gt_depths[i] for i in ids], [fov] * len(ids), ids)
        )
        metrics["gt_kind"] = kind
    if rgbs:
        ids = sorted(rgbs)
        per = {
            i: image_metrics(
                rgbs[i], ingest.image(i).astype(np.float32) / 255.0, ingest.mask(i) > 127
            )
            for i in ids
        }
        metrics["heldout_frames"] = ids
        metrics["heldout_psnr"] = float(np.mean([p["psnr"] for p in per.values()]))
        metrics["heldout_ssim"] = float(np.mean([p["ssim"] for p in per.values()]))
        metrics["per_frame_image"] = {str(i): per[i] for i in ids}
    return metrics


def colourise(depth: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Depth as a turbo colour map (RGB uint8), invalid pixels black."""
    x = np.clip((depth - lo) / max(hi - lo, 1e-9), 0, 1)
    rgb = cv2.cvtColor(
        cv2.applyColorMap((x * 255).astype(np.uint8), cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB
    )
    rgb[depth <= 0] = 0
    return rgb


def error_map(depth: np.ndarray, gt: np.ndarray, affine: bool = False) -> np.ndarray:
    """Per-pixel relative error after median scaling (or, for a relative ground truth, after
    the least-squares scale and shift), 0..0.3 mapped to the colour map."""
    valid = (gt > 0) & (depth > 0)
    err = np.zeros_like(depth)
    if valid.sum() > 1:
        p, g = depth[valid].astype(np.float64), gt[valid].astype(np.float64)
        if affine:
            s, b = affine_fit(p, g)
        else:
            s, b = np.median(g) / np.median(p), 0.0
        err[valid] = np.abs(p * s + b - g) / g
    out = colourise(err, 0.0, 0.3)
    out[~valid] = 0
    return out


def write_preview(
    path: Path,
    ingest,
    depths: dict[int, np.ndarray],
    gt_depths: dict[int, np.ndarray],
    fps: int,
    affine: bool = False,
) -> None:
    """RGB | depth | error (when GT exists), one frame per registered frame."""
    all_d = np.concatenate([d[d > 0] for d in depths.values()]) if depths else np.ones(1)
    lo, hi = np.percentile(all_d, [2, 98]) if all_d.size else (0.0, 1.0)
    frames = []
    for i, d in depths.items():
        panels = [ingest.image(i), colourise(d, lo, hi)]
        if i in gt_depths:
            panels.append(error_map(d, gt_depths[i], affine))
        frames.append(np.concatenate(panels, axis=1))
    if frames:
        write_mp4(path, frames, fps)
