"""`endopipe bench`: the paper's table (or a poses sweep) on fixed-seed synthetic cases, saved
after every case so a crash keeps the finished rows. The cases and variants are bench_plan's,
the runs and their rows bench's, the tables bench_tables'; this module only drives them and
reports."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from endopipe.commands.cases import prepare_case
from endopipe.commands.terminal import console, out

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from endopipe.pipeline.runner import Pipeline


def run_bench_command(
    build_pipeline: Callable[[], Pipeline],
    workdir: Path,
    *,
    quick: bool,
    sets: list[str],
    cases: list[str] | None,
    variants: list[str] | None,
    sweep: str | None,
    profile: bool = False,
    inputs: list[Path] | None = None,
) -> None:
    """Plan, run and tabulate; the extra settings are checked before hours of work."""
    from endopipe.commands import bench as b
    from endopipe.commands import bench_tables as tables
    from endopipe.commands.bench_plan import plan
    from endopipe.pipeline.config import load_config
    from endopipe.pipeline.errors import ConfigError
    from endopipe.pipeline.runner import ensure_writable

    if inputs and not profile:
        raise ConfigError("--input is for --profile: real inputs are profiled, not tabled")
    ensure_writable(workdir)
    pipe = build_pipeline()
    configs = load_config(pipe.stages, [], sets)  # validate extra settings before hours of work
    if profile:
        if quick or variants or sweep:
            raise ConfigError(
                "--profile runs each case once with the defaults: no --quick, --variant or --sweep"
            )
        named = cases or ([] if inputs else ["colon"])  # inputs alone: only those
        bench_cases = plan(False, named).cases if named else []
        return run_profile(pipe, workdir, configs, bench_cases, inputs)
    bench_plan = plan(quick, cases, variants, sweep)
    name, write_csv, table_of, collect = "bench", tables.write_csv, tables.markdown_table, None
    if sweep is not None:
        name, write_csv, table_of = sweep, tables.write_pose_csv, tables.pose_table
        collect = b.pose_row

    def save(rows: list[dict]) -> None:  # after every run: a crash keeps the finished rows
        write_csv(workdir / f"{name}.csv", rows)
        (workdir / f"{name}.md").write_text(table_of(rows) + "\n")

    t0 = time.perf_counter()
    rows = b.run_bench(pipe, workdir, bench_plan, prepare_case, console, sets, save, collect)
    save(rows)
    out.print(table_of(rows), markup=False, highlight=False, soft_wrap=True)
    out.print(
        f"bench finished in {time.perf_counter() - t0:.0f} s; "
        f"{workdir / f'{name}.csv'}, {workdir / f'{name}.md'}"
    )


def run_profile(
    pipe: Pipeline, workdir: Path, configs: dict, cases: list, inputs: list[Path] | None
) -> None:
    """Each bench case and each real input from nothing; profile.md and profile.csv."""
    from pathlib import Path

    from endopipe.commands import bench as b
    from endopipe.commands import profile as p

    def prepare(source: Path, where: Path, name: str) -> Path:
        return prepare_case(source, where, name, None)

    sources = [(c.name, b.case_input(workdir / "inputs", c, console)) for c in cases]
    sources += [(Path(i).stem or Path(i).name, Path(i)) for i in inputs or []]
    rows: list = []
    for name, source in sources:
        console.print(f"[bold cyan]profile: {name}[/bold cyan]")
        rows += p.profile_case(pipe, source, workdir / "profile" / name, configs, prepare, console)
        p.write_profile_csv(workdir / "profile.csv", rows)
        (workdir / "profile.md").write_text(p.profile_table(rows) + "\n")
    out.print(p.profile_table(rows), markup=False, highlight=False, soft_wrap=True)
    out.print(f"profile: {workdir / 'profile.md'}, {workdir / 'profile.csv'}")
