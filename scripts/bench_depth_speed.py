"""Depth-map speed of the depth stage's renderer on a finished case, without writing anything.

Run: `.venv/bin/python scripts/bench_depth_speed.py WORKDIR/CASE [--set depth.key=value ...]`
(a case run up to nerf, e.g. a bench case under WORKDIR/runs/). Bakes as the depth stage does
(the fine bake and the far bake), then times one depth map per registered frame, with the
stage's thread setting: the figure the depth stage's "ms per frame" gives without the file
writes. A benchmark, not a test: the machine's load moves it.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from endopipe.cli import build_pipeline
from endopipe.pipeline.config import load_config
from endopipe.stages.centerline.view import CenterlineView
from endopipe.stages.depth.renderer import FieldSight
from endopipe.stages.depth.stage import torch_threads
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import PosesView


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("case", type=Path)
    parser.add_argument("--set", dest="sets", action="append", default=[], help="depth.key=value")
    args = parser.parse_args()
    cfg = load_config(build_pipeline().stages, [], args.sets)["depth"].model_copy(
        update={"colour": False}
    )
    poses = PosesView(args.case / "02_poses")
    sight = FieldSight.open(
        cfg,
        IngestView(args.case / "01_ingest"),
        poses,
        CenterlineView(args.case / "03_centerline"),
        NerfView(args.case / "04_nerf"),
    )
    render, camera, c2w, bake_s = sight.render, sight.camera, sight.c2w, sight.bake_s
    times = []
    with torch_threads(1 if cfg.renderer == "baked" else None):
        for i in poses.registered:
            t0 = time.perf_counter()
            render(camera, c2w[i], i, False)
            times.append(time.perf_counter() - t0)
    print(
        f"bake {bake_s:.1f} s; depth map median {1000 * np.median(times):.1f} ms "
        f"over {len(times)} frames ({camera.width}x{camera.height})"
    )


if __name__ == "__main__":
    main()
