"""How many samples a ray a dynamic field's depth needs (`depth.dynamic_samples`): a finished
case's frames re-rendered at several settings, as the depth stage renders them.

    .venv/bin/python scripts/depth_samples.py WORKDIR/CASE [--every 15] [--samples 16,8 24,12]

For each setting: seconds a frame, the share of the view (tools left out) that gets a depth
(the rest: weights spread over no one surface, `depth.max_spread`), and, where the case has
ground truth, the per-frame median-scaled AbsRel on the pixels it covers and on those it adds
over the first setting. A benchmark, not a test: the machine's load moves the timing.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from endopipe.stages.centerline.view import CenterlineView
from endopipe.stages.depth.config import DepthConfig
from endopipe.stages.depth.evaluate import ground_truth_depths, inside_view
from endopipe.stages.depth.renderer import make_renderer
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.mesh.evaluation import case_ground_truth
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import PosesView


def rel_errors(depth: np.ndarray, truth: np.ndarray, covered: np.ndarray) -> np.ndarray:
    """Per-pixel |s d - g| / g on `covered`, s the frame's median ratio there."""
    s = np.median(truth[covered]) / np.median(depth[covered])
    return np.abs(depth * s - truth) / np.maximum(truth, 1e-9)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("case", type=Path)
    parser.add_argument("--every", type=int, default=15, help="render every Nth posed frame")
    parser.add_argument("--samples", nargs="+", default=["16,8", "20,10", "24,12", "32,16"])
    args = parser.parse_args()
    case = args.case
    ingest, poses = IngestView(case / "01_ingest"), PosesView(case / "02_poses")
    nerf, prior = NerfView(case / "04_nerf"), CenterlineView(case / "03_centerline").prior()
    k = poses.intrinsics
    if (k.width, k.height) != (ingest.width, ingest.height):
        k = k.scaled(ingest.width, ingest.height)
    c2w = nerf.c2w(poses)
    frames = sorted(c2w)[1 :: args.every]
    gt = case_ground_truth(json.loads((case / "case.json").read_text()).get("gt_dir"))
    truth = ground_truth_depths(gt, ingest, frames)
    inside = inside_view(ingest)
    tissue = {}
    for i in frames:
        tool = ingest.tool_mask(i)
        tissue[i] = inside if tool is None else inside & ~tool
    first: dict[int, np.ndarray] | None = None
    for setting in args.samples:
        coarse, fine = (int(v) for v in setting.split(","))
        model = nerf.model("cpu")
        cfg = DepthConfig(dynamic_samples=(coarse, fine))
        render = make_renderer(cfg, model, prior, [c2w[i] for i in poses.registered], k, nerf)
        t0 = time.perf_counter()
        depth = {i: render(k, c2w[i], i, False)["depth"] for i in frames}
        per_frame = (time.perf_counter() - t0) / len(frames)
        covered = {i: tissue[i] & (depth[i] > 0) for i in frames}
        share = np.mean([covered[i].sum() / max(tissue[i].sum(), 1) for i in frames])
        line = f"{coarse} + {fine}: {per_frame:.2f} s a frame, depth on {share:.1%} of the tissue"
        known = {i: covered[i] & (truth[i] > 0) for i in frames if i in truth}
        scored = [i for i in known if known[i].any()]
        if scored:
            rel = {i: rel_errors(depth[i], truth[i], known[i]) for i in scored}
            line += f"; AbsRel {np.mean([rel[i][known[i]].mean() for i in scored]):.4f}"
            if first is not None:
                added = np.concatenate([rel[i][known[i] & ~(first[i] > 0)] for i in scored])
                if added.size:
                    line += f" ({added.mean():.4f} on the pixels it adds)"
        print(line)
        if first is None:
            first = depth


if __name__ == "__main__":
    main()
