"""Time of one NeRF training step on a finished case, at a chosen point of the schedule.

Run: `.venv/bin/python scripts/bench_nerf_step.py WORKDIR/CASE [--at 1200] [--steps 30]
[--threads 2] [--set nerf.key=value ...]` (a case run up to centerline or further). Sets up the
trainer as the nerf stage does (`set_up_training`), jumps to step `--at` (the grid at the
resolution the schedule has there), runs 5 steps to warm up, then times `--steps` steps. Writes
nothing into the case. A benchmark, not a test: the machine's load moves it. `--profile N`
then runs N more steps under torch.profiler and prints the operators by their own CPU time
(where a step's time goes; the shares hold on a loaded machine, the milliseconds do not).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import torch

from endopipe.cli import build_pipeline
from endopipe.pipeline.config import load_config
from endopipe.stages.centerline.view import CenterlineView
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.nerf.stage import set_up_training
from endopipe.stages.poses.view import PosesView


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("case", type=Path)
    parser.add_argument("--at", type=int, default=1200, help="step of the schedule to time")
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--set", action="append", default=[], dest="sets")
    parser.add_argument("--profile", type=int, default=0, help="profile this many more steps")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    cfg = load_config(build_pipeline().stages, [str(args.case / "config.yaml")], args.sets)["nerf"]
    ingest = IngestView(args.case / "01_ingest")
    poses = PosesView(args.case / "02_poses")
    centerline = CenterlineView(args.case / "03_centerline")
    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        trainer = set_up_training(cfg, ingest, poses, centerline, Path(out), lambda _: None).trainer
        setup_s = time.perf_counter() - t0
        trainer.step_i = args.at
        for _ in range(5):
            trainer.step()
        t0 = time.perf_counter()
        for _ in range(args.steps):
            trainer.step()
        ms = 1000 * (time.perf_counter() - t0) / args.steps
        if args.profile:
            with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
                for _ in range(args.profile):
                    trainer.step()
            print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=25))
    res = (
        max(trainer.model.field.density_grid.res)
        if hasattr(trainer.model.field, "density_grid")
        else None
    )
    print(
        f"{ms:.1f} ms a step at step {args.at} ({res} grid nodes along the longest side), "
        f"{args.threads} threads; set-up {setup_s:.1f} s"
    )


if __name__ == "__main__":
    main()
