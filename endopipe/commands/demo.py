"""`endopipe demo`: a small synthetic colon through every stage, so a new user sees the whole
pipeline work (and where its outputs go) before giving it their own video."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from endopipe.commands.cases import prepare_case
from endopipe.commands.run import print_record
from endopipe.commands.synth import write_synth
from endopipe.commands.terminal import console, out

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from endopipe.pipeline.runner import Pipeline


def run_demo(build_pipeline: Callable[[], Pipeline], workdir: Path, frames: int) -> None:
    """Synthesise the input once (kept for later demos), run it as the case `demo`. The DAG is
    built after synthesis: a workdir that cannot be written fails before torch loads."""
    from endopipe.pipeline.config import load_config
    from endopipe.pipeline.runner import ensure_writable
    from endopipe.synth import SynthConfig

    ensure_writable(workdir)
    case_src = workdir / "demo_input"
    cfg = SynthConfig(seed=0, frames=frames, width=320, height=256, shape="colon")
    t0 = time.perf_counter()
    if not (case_src / "intrinsics.json").exists():
        console.print(f"[bold]synthesising[/bold] a {frames}-frame colon into {case_src}")
        write_synth(case_src, cfg)
    pipe = build_pipeline()
    configs = load_config(pipe.stages, ["demo"] if has_preset("demo") else [], [])
    case_dir = prepare_case(case_src, workdir, "demo", None)
    record = pipe.run(case_dir, configs, console=console)
    print_record(record, case_dir)
    out.print(f"demo finished in {time.perf_counter() - t0:.1f} s; outputs:")
    for stage in pipe.stages:
        out.print(f"  {stage.name:<11} {case_dir / pipe.folder_name(stage.name)}")


def has_preset(name: str) -> bool:
    """Whether configs/ ships the preset (a trimmed install may not)."""
    from endopipe.pipeline.config import CONFIG_DIR

    return (CONFIG_DIR / f"{name}.yaml").is_file()
