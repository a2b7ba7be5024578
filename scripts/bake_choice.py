"""How a trained case's depth read-out choices score against its ground truth: the baked
iso-surface's reach and level, the spread limit, holding to the SfM points, the field itself.

Run: `.venv/bin/python scripts/bake_choice.py WORKDIR/CASE [--every 4] [--bake REACH,LEVEL ...]
[--spread 0.15,0.3,none] [--anchor] [--field]` (a case run through nerf). Each `--bake` bakes
the field as the depth stage does, with the iso-surface up to REACH lumen radii (0: none, the
far bake alone) at LEVEL times the calibrated surface level, then scores the depth maps of
every `--every`-th registered frame at each `--spread` limit (AbsRel median-scaled per frame,
on the pixels the depth stage scores; coverage of those pixels). `--anchor` also scores them
held to the SfM points (`depth.anchor=points`), `--field` the field volume-rendered (its
weights' median). One torch thread; writes nothing into the case. A benchmark: run it alone.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

import endopipe.stages.nerf.render as render
from endopipe.stages.centerline.view import CenterlineView
from endopipe.stages.depth.anchor import Anchor
from endopipe.stages.depth.evaluate import ground_truth_depths, inside_view, scored_pixels
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.metrics.depth import depth_sequence_metrics
from endopipe.stages.nerf.baked import BakedSurface, FarSettings
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import PosesView


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", type=Path)
    ap.add_argument("--every", type=int, default=4)
    ap.add_argument("--bake", action="append", default=[], help="REACH,LEVEL (e.g. 2.5,1)")
    ap.add_argument("--spread", default="0.15")
    ap.add_argument("--anchor", action="store_true")
    ap.add_argument("--field", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(1)
    ingest = IngestView(args.case / "01_ingest")
    poses = PosesView(args.case / "02_poses")
    prior = CenterlineView(args.case / "03_centerline").prior()
    nerf = NerfView(args.case / "04_nerf")
    model = nerf.model(render.pick_device("cpu"))
    k = poses.intrinsics
    if (k.width, k.height) != (ingest.width, ingest.height):
        k = k.scaled(ingest.width, ingest.height)
    c2w = nerf.c2w(poses)
    registered = list(poses.registered)
    truth = ground_truth_depths(ingest.ground_truth(), ingest, registered[:: args.every])
    keep = sorted(truth)
    masks, _ = scored_pixels(ingest, keep, inside_view(ingest))
    anchor = Anchor.open("points", ingest, poses, 0.025, 0.05) if args.anchor else None
    print(f"{len(keep)} frames; prior {prior.kind}", flush=True)

    def score(name: str, maps: list[np.ndarray]) -> None:
        m = depth_sequence_metrics(maps, [truth[i] for i in keep], masks)
        cover = np.mean([((d > 0) & s).sum() / s.sum() for d, s in zip(maps, masks, strict=True)])
        print(f"{name}: AbsRel {m['median_scaled']['abs_rel']:.4f}, coverage {cover:.3f}")
        if anchor is not None:
            pairs = zip(keep, maps, strict=True)
            held = [anchor.apply(i, d.astype(np.float32))[0] for i, d in pairs]
            m = depth_sequence_metrics(held, [truth[i] for i in keep], masks)
            print(f"  held to the SfM points: AbsRel {m['median_scaled']['abs_rel']:.4f}")

    calibrated = render.surface_density_level
    for spec in args.bake:
        reach, level = (float(v) for v in spec.split(","))
        render.surface_density_level = lambda *a, level=level, **kw: calibrated(*a, **kw) * level
        t0 = time.perf_counter()
        baked = BakedSurface.bake(
            model, prior, [c2w[i] for i in registered], k, reach_radii=reach,
            min_component_radii=0.5, far=FarSettings(),
        )  # fmt: skip
        print(f"bake reach {reach} level x{level}: {time.perf_counter() - t0:.1f} s")
        for limit in args.spread.split(","):
            spread = None if limit == "none" else float(limit)
            t0 = time.perf_counter()
            maps = [baked.render_depth(k, c2w[i], 0.5, False, spread)["depth"] for i in keep]
            ms = 1000 * (time.perf_counter() - t0) / len(keep)
            score(f"  spread {limit} ({ms:.0f} ms a map)", maps)
    render.surface_density_level = calibrated
    if args.field:
        t0 = time.perf_counter()
        maps = [render.render_image(model, prior, k, c2w[i])["median"] for i in keep]
        ms = 1000 * (time.perf_counter() - t0) / len(keep)
        score(f"field, its weights' median, any spread ({ms:.0f} ms a map)", maps)


if __name__ == "__main__":
    main()
