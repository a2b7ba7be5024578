"""Held-out and training PSNR against training time, for one finished case: where more time
would take the field.

Run: `.venv/bin/python scripts/psnr_curve.py WORKDIR/CASE [--every 250] [--frames 4]
[--threads 1] [--set nerf.key=value ...] [--csv OUT.csv] [--renders DIR] [--depth N]` (a case
run up to centerline or further). Sets up the trainer as the nerf stage does
(`set_up_training`, the case's own config.yaml and the `--set`s), trains, and every `--every`
steps renders `--frames` held-out frames and as many training frames (spread over the
sequence) in full, scoring each on the pixels the stage's PSNR counts (the ingest masks and
the lens). Prints one row per point: step, training seconds so far, training PSNR, held-out
PSNR; the neighbour average of the same held-out frames is printed once; `--renders` writes
each scored frame beside its last render; `--depth N` scores the field's depth at the end on
N frames spread over the sequence against the case's ground truth (the depth stage's
protocol, median-scaled per frame; the field alone, before the depth stage). Writes nothing
into the case. A benchmark: run it alone.
"""

from __future__ import annotations

import argparse
import csv
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import yaml

from endopipe.cli import build_pipeline
from endopipe.pipeline.config import load_config, read_yaml
from endopipe.stages.camera import lens_valid_mask
from endopipe.stages.centerline.view import CenterlineView
from endopipe.stages.depth.evaluate import ground_truth_depths, inside_view, scored_pixels
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.metrics.baselines import neighbour_average, neighbour_frames
from endopipe.stages.metrics.depth import depth_sequence_metrics
from endopipe.stages.nerf import losses
from endopipe.stages.nerf.render import render_image
from endopipe.stages.nerf.stage import set_up_training
from endopipe.stages.poses.view import PosesView


def spread(ids: list[int], n: int) -> list[int]:
    """`n` of `ids` evenly spread (all when fewer)."""
    if len(ids) <= n:
        return list(ids)
    return [ids[int(round(k))] for k in np.linspace(0, len(ids) - 1, n)]


def nerf_config(case: Path, sets: list[str]):
    """The nerf settings the case last ran with (its config.yaml's nerf section) and `sets`;
    the other stages' settings are not read (they may come from another version)."""
    nerf = [s for s in build_pipeline().stages if s.name == "nerf"]
    section = {"nerf": read_yaml(case / "config.yaml").get("nerf") or {}}
    with tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False) as fh:
        yaml.safe_dump(section, fh)
    try:
        return load_config(nerf, [fh.name], sets, use_default_file=False)["nerf"]
    finally:
        Path(fh.name).unlink()


def field_depth_line(run, ingest: IngestView, ids: list[int]) -> str:
    """The field's depth on frames `ids` against the case's ground truth, median-scaled per
    frame as the depth stage scores it, on the same pixels (inside the view, off tools)."""
    truth = ground_truth_depths(ingest.ground_truth(), ingest, ids)
    if not truth:
        return "depth: the case has no ground-truth depth"
    model = run.trainer.model.eval()
    ours = {}
    for i in sorted(truth):
        p = run.pos[i]
        with model.at_frame(p):
            ours[i] = render_image(model, run.prior, run.camera, run.c2w[p], frame=p)["depth"]
    keep = sorted(truth)
    masks, _ = scored_pixels(ingest, keep, inside_view(ingest))
    m = depth_sequence_metrics([ours[i] for i in keep], [truth[i] for i in keep], masks)
    block = m["median_scaled"]
    return f"field depth, {len(keep)} frames: AbsRel {block['abs_rel']:.4f} median-scaled"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", type=Path)
    ap.add_argument("--every", type=int, default=250, help="steps between evaluations")
    ap.add_argument("--frames", type=int, default=4, help="held-out (and training) frames")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--set", action="append", default=[], dest="sets")
    ap.add_argument("--csv", type=Path, default=None)
    ap.add_argument("--renders", type=Path, default=None, help="frame | render PNGs, at the end")
    ap.add_argument("--depth", type=int, default=0, help="frames whose depth is scored at the end")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    cfg = nerf_config(args.case, args.sets)
    ingest = IngestView(args.case / "01_ingest")
    poses = PosesView(args.case / "02_poses")
    centerline = CenterlineView(args.case / "03_centerline")
    with tempfile.TemporaryDirectory() as out:
        run = set_up_training(cfg, ingest, poses, centerline, Path(out), print)
        trainer, cfg = run.trainer, run.cfg
        lens = lens_valid_mask(run.camera)
        held = spread(run.held_ids, args.frames)
        train = spread(run.train_ids, args.frames)
        order = [f.index for f in ingest.frames]

        def image(i: int) -> np.ndarray:
            return ingest.image(i).astype(np.float32) / 255.0

        def usable(i: int) -> np.ndarray:
            return (ingest.mask(i) > 127) & lens

        def psnr_of(rgb: np.ndarray, i: int) -> float:
            m = usable(i)
            return losses.psnr(float(((rgb - image(i)) ** 2).mean(-1)[m].mean()))

        nb = []
        for i in held:
            near = neighbour_frames(i, order, set(run.held_ids))
            if near:
                nb.append(psnr_of(neighbour_average([image(j) for j in near]), i))
        print(f"neighbour average of the held-out frames: {np.mean(nb):.2f} dB ({len(nb)})")

        renders: dict[int, np.ndarray] = {}

        def score(ids: list[int]) -> float:
            model = trainer.model.eval()
            vals = []
            for i in ids:
                p = run.pos[i]
                with model.at_frame(p):
                    rgb = render_image(model, run.prior, run.camera, run.c2w[p], frame=p)["rgb"]
                vals.append(psnr_of(rgb, i))
                renders[i] = rgb
            trainer.model.train()
            return float(np.mean(vals))

        rows = []
        while trainer.step_i < cfg.train.steps and trainer.progress < 1.0:
            t0 = time.perf_counter()
            end = min(cfg.train.steps, trainer.step_i + args.every)
            while trainer.step_i < end and trainer.progress < 1.0:
                trainer.step()
            trainer.elapsed += time.perf_counter() - t0
            row = {
                "step": trainer.step_i,
                "train_s": round(trainer.elapsed, 1),
                "train_psnr": round(score(train), 2),
                "heldout_psnr": round(score(held), 2),
            }
            rows.append(row)
            print(
                f"step {row['step']:6d}  {row['train_s']:7.1f} s  training {row['train_psnr']:.2f}"
                f" dB  held-out {row['heldout_psnr']:.2f} dB",
                flush=True,
            )
        if args.depth:
            print(field_depth_line(run, ingest, spread(run.ids, args.depth)), flush=True)
        if args.renders:
            import cv2

            args.renders.mkdir(parents=True, exist_ok=True)
            for i, rgb in renders.items():
                pair = np.concatenate([image(i), np.clip(rgb, 0, 1)], 1)
                kind = "heldout" if i in held else "train"
                name = args.renders / f"{kind}_{i:06d}.png"
                cv2.imwrite(str(name), (pair[..., ::-1] * 255).round().astype(np.uint8))
    if args.csv:
        with open(args.csv, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)


if __name__ == "__main__":
    main()
