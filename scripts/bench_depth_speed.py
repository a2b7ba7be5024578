"""Depth-map speed of the baked surface on a finished case, without writing anything.

Run: `.venv/bin/python scripts/bench_depth_speed.py WORKDIR/CASE` (a case run up to nerf, e.g. a
bench case under WORKDIR/runs/). Prints the bake time and the median time of one
`BakedSurface.render_depth` per registered frame: the figure the depth stage's "ms per frame"
gives without the file writes. A benchmark, not a test: the machine's load moves it.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from endopipe.stages.centerline.view import CenterlineView
from endopipe.stages.depth.config import DepthConfig
from endopipe.stages.nerf.baked import BakedSurface
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import PosesView


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("case", type=Path)
    case = parser.parse_args().case
    model = NerfView(case / "04_nerf").model()
    prior = CenterlineView(case / "03_centerline").prior()
    poses = PosesView(case / "02_poses")
    camera, cfg = poses.intrinsics, DepthConfig()
    c2ws = [poses.c2w[i] for i in poses.registered]
    t0 = time.perf_counter()
    baked = BakedSurface.bake(
        model, prior, c2ws, camera, cfg.bake_voxels_per_radius, cfg.bake_density_level
    )
    bake_s = time.perf_counter() - t0
    times = []
    for c2w in c2ws:
        t0 = time.perf_counter()
        baked.render_depth(camera, c2w)
        times.append(time.perf_counter() - t0)
    print(
        f"bake {bake_s:.1f} s; render_depth median {1000 * np.median(times):.1f} ms "
        f"over {len(times)} frames ({camera.width}x{camera.height})"
    )


if __name__ == "__main__":
    main()
