"""The GPU figures of docs/results.md: NeRF training and depth maps of finished cases, on CUDA.

Run: `python scripts/bench_gpu.py WORKDIR/CASE [WORKDIR/CASE ...] [--config gpu]
[--set key=value ...] [--renderer field] [--out DIR]` on cases whose ingest, poses and
centerline are done (e.g. by `endopipe bench --profile` on the CPU machine). For each case the
NeRF and the depth stage run again from nothing with the configuration given (`gpu` by default),
once per depth renderer named, and each stage's wall time, CPU time, peak memory and own speed
(steps, rays a second, ms a depth map) are printed beside the accuracy, as `bench --profile`
prints them. The stages before the NeRF are not re-run: they are the CPU's work either way.
A benchmark, not a test: nothing here runs in CI.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import torch
from rich.console import Console

from endopipe.cli import build_pipeline
from endopipe.commands.profile import ProfileRow, profile_rows, profile_table
from endopipe.pipeline.config import load_config
from endopipe.pipeline.runner import Pipeline
from endopipe.stages.nerf.summary import NerfSummary

STAGES = ("nerf", "depth")


def device_name() -> str:
    if torch.cuda.is_available():
        return f"{torch.cuda.get_device_name(0)}, torch {torch.__version__}"
    return f"CPU ({platform.processor() or platform.machine()}), torch {torch.__version__}"


def run_case(
    pipe: Pipeline, case_dir: Path, configs: dict, renderer: str, console: Console
) -> list[ProfileRow]:
    """NeRF and depth from nothing (renderer `renderer`), then the rows of those two stages."""
    configs = dict(configs)
    configs["depth"] = configs["depth"].model_copy(update={"renderer": renderer})
    t0 = time.perf_counter()
    pipe.run(case_dir, configs, until="depth", from_stage="nerf", console=console)
    elapsed = time.perf_counter() - t0
    rows = [r for r in profile_rows(pipe, case_dir, elapsed) if r.stage in (*STAGES, "all")]
    nerf: NerfSummary = pipe.view(case_dir, "nerf").summary
    for r in rows:
        if r.stage == "nerf" and r.wall_s:
            r.note += f", {nerf.steps / r.wall_s:.1f} steps/s (stage wall)"
        if r.stage == "all":
            r.stage = f"nerf+depth ({renderer})"
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", type=Path, nargs="+")
    parser.add_argument("--config", dest="configs", action="append", default=None)
    parser.add_argument("--set", dest="sets", action="append", default=[])
    parser.add_argument("--renderer", dest="renderers", action="append", default=None)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    console = Console(stderr=True)
    pipe = build_pipeline()
    configs = load_config(pipe.stages, args.configs or ["gpu"], args.sets)
    header = f"device: {device_name()}"
    console.print(header)
    rows: list[ProfileRow] = []
    for case_dir in args.cases:
        for renderer in args.renderers or ["baked"]:
            try:
                rows += run_case(pipe, case_dir, configs, renderer, console)
            except Exception as e:  # a benchmark reports a failed variant and goes on
                rows.append(ProfileRow(case=case_dir.name, stage=renderer, note=f"failed: {e}"))
            console.print(profile_table(rows))
    table = f"{header}\n\n{profile_table(rows)}\n"
    print(table)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "bench_gpu.md").write_text(table)
        (args.out / "bench_gpu.json").write_text(
            json.dumps([r.model_dump() for r in rows], indent=1)
        )


if __name__ == "__main__":
    main()
