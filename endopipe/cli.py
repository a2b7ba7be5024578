"""The composition root: wires the stages into the DAG and exposes the commands.

Every failure the user can act on ends as one line on stderr and a non-zero exit code.
"""

from __future__ import annotations

import importlib
import shlex
import sys
import time
import traceback
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table
from rich.text import Text

from endopipe.pipeline.errors import EndopipeError

# The engine (pydantic, yaml) and the stages (torch, cv2) are imported by the commands that use
# them: `endopipe --help` and `status` start in a fraction of a second.
if TYPE_CHECKING:
    from endopipe.commands.batch.rows import CaseRow, CaseTask
    from endopipe.pipeline.runner import Pipeline, RunRecord
    from endopipe.pipeline.stage import Stage

console = Console(stderr=True)
out = Console()
app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="endopipe: monocular endoscopic video -> poses, depth, mesh and an evaluation report.",
)
DEFAULT_WORKDIR = Path("workdir")
#: Options several commands share, spelt once.
WorkdirOption = Annotated[Path, typer.Option(help="Output root.")]
ConfigOption = Annotated[
    list[str] | None, typer.Option("--config", help="Preset name or YAML file; repeatable.")
]
SetOption = Annotated[list[str] | None, typer.Option("--set", help="stage.key=value; repeatable.")]


#: The DAG in order: each stage's module and class.
DAG = (
    ("endopipe.stages.ingest.stage", "Ingest"),
    ("endopipe.stages.poses.stage", "Poses"),
    ("endopipe.stages.centerline.stage", "Centerline"),
    ("endopipe.stages.nerf.stage", "Nerf"),
    ("endopipe.stages.depth.stage", "Depth"),
    ("endopipe.stages.mesh.stage", "Mesh"),
    ("endopipe.stages.report.stage", "Report"),
)


def all_stages() -> list[type[Stage]]:
    """The DAG's stage classes, imported (torch, cv2, pycolmap): for commands that run them."""
    return [getattr(importlib.import_module(module), cls) for module, cls in DAG]


def build_pipeline() -> Pipeline:
    from endopipe.pipeline.runner import Pipeline

    return Pipeline(all_stages())


def planning_pipeline() -> Pipeline:
    """The DAG read from the stages' source, not imported: plans, configs and folders only,
    so `status`, `clean`, `stages` and `export` start in a fraction of a second."""
    from endopipe.pipeline.declared import declared
    from endopipe.pipeline.runner import Pipeline

    return Pipeline([declared(module, cls) for module, cls in DAG])


def case_name_for(input_path: Path) -> str:
    p = input_path.resolve()
    if p.is_file() and p.name == "video.mp4" and (p.parent / "intrinsics.json").exists():
        return p.parent.name
    if p.is_dir() and p.name == "frames":
        return p.parent.name
    return p.stem if p.is_file() else p.name


def prepare_case(
    input_path: Path,
    workdir: Path,
    name: str | None,
    intrinsics: Path | None,
    input_format: str | None = None,
) -> Path:
    """Check the input, then create the case folder and its case.json (only then)."""
    from endopipe.pipeline.runner import ensure_writable
    from endopipe.pipeline.stage import CaseInfo, write_json
    from endopipe.stages.io.sources import open_input

    source = open_input(input_path, intrinsics, format=input_format)
    digest = source.digest()
    ensure_writable(workdir)
    case_dir = workdir / (name or case_name_for(input_path))
    case_dir.mkdir(parents=True, exist_ok=True)
    info = CaseInfo(
        name=case_dir.name,
        input=str(Path(input_path).resolve()),
        kind=source.kind,
        input_digest=digest,
        intrinsics_file=str(intrinsics.resolve()) if intrinsics else None,
        gt_dir=str(source.gt_dir) if source.gt_dir else None,
    )
    case_json = case_dir / "case.json"
    if not case_json.exists() or CaseInfo.load(case_dir) != info:
        tmp = case_dir / ".case.json.tmp"
        write_json(tmp, info.model_dump())
        tmp.replace(case_json)
    return case_dir


def resolve_case(case: str, workdir: Path) -> Path:
    for candidate in (Path(case), workdir / case):
        if (candidate / "case.json").is_file():
            return candidate
    raise EndopipeError(
        f"no endopipe case at {case} (nor {workdir / case}); run `endopipe run INPUT` first"
    )


def print_record(record: RunRecord, case_dir: Path) -> None:
    ran = [s.stage for s in record.stages if s.status == "ran"]
    cached = [s.stage for s in record.stages if s.status == "cached"]
    console.print(
        f"[bold]{record.case}[/bold]: ran {len(ran)} stage(s), {len(cached)} cached, "
        f"{record.wall_s:.1f} s -> {case_dir}"
    )


@app.command()
def run(
    input: Annotated[
        Path, typer.Argument(help="Video file, image folder or endopipe case folder.")
    ],
    workdir: WorkdirOption = DEFAULT_WORKDIR,
    name: Annotated[str | None, typer.Option(help="Case name (default: from the input).")] = None,
    config: ConfigOption = None,
    set_: SetOption = None,
    intrinsics: Annotated[
        Path | None, typer.Option(help="intrinsics.json for the input's frames.")
    ] = None,
    from_stage: Annotated[
        str | None, typer.Option("--from", help="Re-run from this stage.")
    ] = None,
    until: Annotated[str | None, typer.Option(help="Stop after this stage.")] = None,
    force: Annotated[bool, typer.Option(help="Ignore the cache.")] = False,
    dry_run: Annotated[bool, typer.Option(help="Show what would run, run nothing.")] = False,
    wait: Annotated[bool, typer.Option(help="Wait for another run on the same case.")] = False,
    quiet: Annotated[bool, typer.Option(help="No progress output.")] = False,
) -> None:
    """Run the pipeline on INPUT: what is stale runs, what is fresh is reused."""
    from endopipe.pipeline.config import load_config

    pipe = build_pipeline()
    for stage in (from_stage, until):
        if stage is not None:
            pipe.index(stage)
    configs = load_config(pipe.stages, config or [], set_ or [])
    case_dir = prepare_case(input, workdir, name, intrinsics)
    record = pipe.run(
        case_dir,
        configs,
        until=until,
        from_stage=from_stage,
        force=force,
        dry_run=dry_run,
        wait_for_lock=wait,
        console=console,
        quiet=quiet,
    )
    if dry_run:
        for s in record.stages:
            out.print(
                f"{s.stage:<12} {'cached' if s.status == 'cached' else 'would run'}  ({s.reason})"
            )
        return
    print_record(record, case_dir)
    print_pose_doubt(pipe, case_dir)


def print_pose_doubt(pipe, case_dir: Path) -> None:
    """Doubtful poses as the run's last line: everything after the poses inherits them, and
    the stage log that said so has scrolled away."""
    try:
        verdict = pipe.view(case_dir, "poses").verdict()
    except (OSError, ValueError):  # no poses folder (yet), or one written by an older version
        return
    if verdict is not None and verdict.status == "doubtful":
        others = "".join(
            f"; the {m} mapper's poses were sound on their own (`--set poses.mapper={m}` "
            "keeps them)"
            for m in verdict.sound_others()
        )
        console.print(
            f"[bold yellow]poses doubtful:[/bold yellow] {escape('; '.join(verdict.reasons))} "
            f"(02_poses/verdict.json; the report's poses section names the frames){escape(others)}",
            soft_wrap=True,
        )


@app.command()
def status(
    case: Annotated[str, typer.Argument(help="Case folder or name under --workdir.")],
    workdir: WorkdirOption = DEFAULT_WORKDIR,
    config: ConfigOption = None,
    set_: SetOption = None,
) -> None:
    """Each stage of CASE: fresh, stale (and why), missing or running. Judged against the
    configuration CASE was last run with; with --config/--set: would that config re-run?"""
    from endopipe.pipeline.config import load_config

    pipe = planning_pipeline()
    case_dir = resolve_case(case, workdir)
    given = bool(config or set_)
    configs = load_config(pipe.stages, config or [], set_ or []) if given else None
    plan = pipe.status(case_dir, configs)
    running = pipe.in_progress(case_dir)
    against = "the given --config/--set" if given else "the configuration of its last run"
    table = Table(title=f"{case_dir.name}", caption=f"judged against {against}")
    for col in ("stage", "state", "why", "folder"):
        table.add_column(col)
    for p in plan:
        state = "fresh" if p.fresh else ("missing" if p.reason == "missing" else "stale")
        why = p.reason
        if running is not None and running.running == p.stage:
            since = running.started.split("T")[-1]
            state, why = "running", f"pid {running.pid} on {running.host}, run started {since}"
        colour = {"fresh": "green", "stale": "yellow", "missing": "red", "running": "cyan"}[state]
        table.add_row(p.stage, f"[{colour}]{state}[/{colour}]", escape(why), p.folder)
    out.print(table)
    if running is not None:
        out.print(
            f"a run is in progress (pid {running.pid} on {running.host}): {running.running} is "
            "running; stages after it are judged by what is on disk now",
            highlight=False,
        )


@app.command()
def clean(
    case: Annotated[str, typer.Argument(help="Case folder or name under --workdir.")],
    workdir: WorkdirOption = DEFAULT_WORKDIR,
    stage: Annotated[
        str | None, typer.Option(help="Remove this stage and its downstream only.")
    ] = None,
) -> None:
    """Remove a case's stage outputs (all, or one stage and what depends on it)."""
    pipe = planning_pipeline()
    case_dir = resolve_case(case, workdir)
    if stage is not None:
        pipe.index(stage)
    removed = pipe.clean(case_dir, stage)
    out.print(f"removed {len(removed)} folder(s): {', '.join(removed) or 'none'}")


@app.command()
def export(
    case: Annotated[str, typer.Argument(help="Case folder or name under --workdir.")],
    format_: Annotated[str, typer.Option("--format", help="nerfstudio | colmap | endonerf | ply")],
    out_dir: Annotated[
        Path | None,
        typer.Option("--out", help="Output folder (default: <case>/exports/<format>)."),
    ] = None,
    workdir: WorkdirOption = DEFAULT_WORKDIR,
    symlink: Annotated[
        bool, typer.Option(help="nerfstudio / colmap: symlink the images instead of copying.")
    ] = False,
    endonerf_axes: Annotated[
        str,
        typer.Option(
            help="endonerf: rotation columns of poses_bounds.npy: llff (down, right, back) | "
            "opengl (right, up, back) | opencv (right, down, forward)."
        ),
    ] = "llff",
) -> None:
    """Export a case's poses, frames, depth and mesh for nerfstudio, COLMAP, EndoNeRF or PLY."""
    from endopipe.commands.export import export_case

    case_dir = resolve_case(case, workdir)
    folders = planning_pipeline().folders(case_dir)
    result = export_case(
        case_dir, format_, out_dir, folders=folders, symlink=symlink, endonerf_axes=endonerf_axes
    )
    out.print(f"exported {result.frames} frame(s) as {result.format} to {result.out}")
    for note in result.notes:
        out.print(f"  {note}", markup=False, highlight=False)


@app.command("stages")
def list_stages(
    yaml_: Annotated[bool, typer.Option("--yaml", help="Print configs/default.yaml.")] = False,
) -> None:
    """Every stage with its config fields, types, defaults and help."""
    from endopipe.pipeline.config import default_yaml, describe_fields

    pipe = planning_pipeline()
    if yaml_:
        out.print(default_yaml(pipe.stages), markup=False, highlight=False, soft_wrap=True)
        return
    for stage in pipe.stages:
        needs = ", ".join(stage.needs) or "input"
        out.print(f"[bold]{pipe.folder_name(stage.name)}[/bold]  needs: {needs}  v{stage.version}")
        out.print(f"  {stage.describe()}", markup=False, highlight=False, soft_wrap=True)
        # one line per key (grep-able, never truncated: `endopipe stages | grep steps`),
        # its help below; the default is written as --set and config files take it
        for key, type_name, default, help_text in describe_fields(stage.Config):
            line = Text("  ")
            line.append(f"{stage.name}.{key}", style="bold")
            line.append(f" = {default}  [{type_name}]")
            out.print(line, highlight=False, soft_wrap=True)
            if help_text:
                out.print(f"      {help_text}", markup=False, highlight=False, soft_wrap=True)
        out.print()


@app.command()
def synth(
    out_dir: Annotated[Path, typer.Argument(metavar="OUT", help="Case folder to write.")],
    seed: int = 0,
    frames: int = 60,
    width: int = 320,
    height: int = 256,
    shape: Annotated[str, typer.Option(help="colon | cavity")] = "colon",
    lens: Annotated[
        str, typer.Option(help="pinhole | barrel (OpenCV k1,k2) | fisheye (OpenCV equidistant)")
    ] = "pinhole",
    fov_diag: Annotated[
        float | None,
        typer.Option(
            help="Diagonal field of view, deg (unset: barrel 110, fisheye 140, pinhole 90 "
            "across the width)."
        ),
    ] = None,
    vignetting: Annotated[
        float, typer.Option(help="Corners get 1 - S of the centre's light (linear); 0 = off.")
    ] = 0.0,
) -> None:
    """Write a synthetic lumen case with exact ground truth (depth, poses, mesh, speculars)."""
    from pydantic import ValidationError

    from endopipe.commands.synth import SynthConfig
    from endopipe.pipeline.runner import ensure_writable

    try:
        cfg = SynthConfig(
            seed=seed,
            frames=frames,
            width=width,
            height=height,
            shape=shape,
            lens=lens,
            fov_diag_deg=fov_diag,
            vignetting=vignetting,
        )
    except ValidationError as e:
        err = e.errors()[0]
        raise EndopipeError(f"synth {'.'.join(map(str, err['loc']))}: {err['msg']}") from None
    ensure_writable(out_dir.parent if out_dir.parent != Path("") else Path("."))
    summary = write_synth(out_dir, cfg)
    out.print(
        f"wrote {summary.frames} frames ({shape}, path {summary.path_length_mm:.1f} mm, "
        f"mean radius {summary.mean_radius_mm:.1f} mm) to {out_dir} in {summary.seconds:.1f} s"
    )


def write_synth(out_dir: Path, cfg) -> object:
    from rich.progress import Progress

    from endopipe.commands.synth import generate_case

    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("synth", total=cfg.frames)
        return generate_case(out_dir, cfg, progress=lambda i, n: bar.update(task, completed=i + 1))


@app.command()
def demo(
    workdir: WorkdirOption = DEFAULT_WORKDIR,
    frames: int = 24,
) -> None:
    """Synthesise a small colon case and run every stage on it."""
    from endopipe.commands.synth import SynthConfig
    from endopipe.pipeline.config import load_config
    from endopipe.pipeline.runner import ensure_writable

    ensure_writable(workdir)
    case_src = workdir / "demo_input"
    cfg = SynthConfig(seed=0, frames=frames, width=320, height=256, shape="colon")
    t0 = time.perf_counter()
    if not (case_src / "intrinsics.json").exists():
        console.print(f"[bold]synthesising[/bold] a {frames}-frame colon into {case_src}")
        write_synth(case_src, cfg)
    pipe = build_pipeline()
    configs = load_config(pipe.stages, ["demo"] if _has_preset("demo") else [], [])
    case_dir = prepare_case(case_src, workdir, "demo", None)
    record = pipe.run(case_dir, configs, console=console)
    print_record(record, case_dir)
    out.print(f"demo finished in {time.perf_counter() - t0:.1f} s; outputs:")
    for stage in pipe.stages:
        out.print(f"  {stage.name:<11} {case_dir / pipe.folder_name(stage.name)}")


@app.command()
def bench(
    workdir: Annotated[Path, typer.Option(help="Where cases and results go.")] = Path(
        "workdir/bench"
    ),
    quick: Annotated[
        bool, typer.Option(help="One small colon, three variants (< 10 min).")
    ] = False,
    set_: Annotated[list[str] | None, typer.Option("--set", help="Extra stage.key=value.")] = None,
    case: Annotated[
        list[str] | None, typer.Option("--case", help="Only this bench case (repeatable).")
    ] = None,
    variant: Annotated[
        list[str] | None,
        typer.Option("--variant", help="Only this variant, e.g. full (repeatable)."),
    ] = None,
    sweep: Annotated[
        str | None,
        typer.Option(
            help="poses: the poses stage alone on 10 synthetic cases (shape, seed, texture, "
            "vignetting, lens); poses.csv and poses.md."
        ),
    ] = None,
) -> None:
    """The paper's Table 1 on fixed-seed synthetic cases with ablations; CSV and markdown."""
    from endopipe.commands import bench as b
    from endopipe.pipeline.config import load_config
    from endopipe.pipeline.runner import ensure_writable

    ensure_writable(workdir)
    pipe = build_pipeline()
    load_config(pipe.stages, [], set_ or [])  # validate extra settings before hours of work
    bench_plan = b.plan(quick, case, variant, sweep)
    name, write_csv, table_of, collect = "bench", b.write_csv, b.markdown_table, None
    if sweep is not None:
        name, write_csv, table_of, collect = sweep, b.write_pose_csv, b.pose_table, b.pose_row

    def save(rows: list[dict]) -> None:  # after every run: a crash keeps the finished rows
        write_csv(workdir / f"{name}.csv", rows)
        (workdir / f"{name}.md").write_text(table_of(rows) + "\n")

    t0 = time.perf_counter()
    rows = b.run_bench(pipe, workdir, bench_plan, prepare_case, console, set_ or [], save, collect)
    save(rows)
    out.print(table_of(rows), markup=False, highlight=False, soft_wrap=True)
    out.print(
        f"bench finished in {time.perf_counter() - t0:.0f} s; "
        f"{workdir / f'{name}.csv'}, {workdir / f'{name}.md'}"
    )


def _has_preset(name: str) -> bool:
    from endopipe.pipeline.config import CONFIG_DIR

    return (CONFIG_DIR / f"{name}.yaml").is_file()


# ---------------------------------------------------------------- endopipe batch


def batch_case(task: CaseTask) -> CaseRow:
    """One case of `endopipe batch` with this DAG. Top-level, so executors pickle it by name."""
    from endopipe.commands.batch.case import process_case

    return process_case(task, build_pipeline, prepare_case)


@app.command()
def batch(
    folder: Annotated[
        Path, typer.Argument(help="A data set folder, a folder of videos or cases, or one case.")
    ],
    workdir: WorkdirOption = DEFAULT_WORKDIR,
    config: ConfigOption = None,
    set_: SetOption = None,
    format_: Annotated[
        str,
        typer.Option(
            "--format",
            help="Reader for every case: auto (detect) | case | video | images | hamlyn | c3vd "
            "| simcol3d.",
        ),
    ] = "auto",
    executor: Annotated[str, typer.Option(help="Where cases run: local | slurm | ray.")] = "local",
    jobs: Annotated[
        int | None,
        typer.Option(
            min=1,
            help="Cases at once. local: worker processes (default 1); slurm: array "
            "parallelism (default from the cluster config); ray: slots of a local cluster.",
        ),
    ] = None,
    until: Annotated[str | None, typer.Option(help="Stop each case after this stage.")] = None,
    cluster_config: Annotated[
        Path | None, typer.Option(help="Slurm / Ray settings (default configs/cluster.yaml).")
    ] = None,
    ray_address: Annotated[
        str | None,
        typer.Option(help="Ray cluster to join (auto, ray://host:10001); default: a local one."),
    ] = None,
    dry_run: Annotated[bool, typer.Option(help="List the cases and readers only.")] = False,
) -> None:
    """Run every case under FOLDER through the pipeline; write batch.csv and batch.html."""
    from endopipe.commands.batch.command import run_batch

    run_batch(
        build_pipeline(),
        batch_case,
        folder,
        workdir,
        config_files=config or [],
        sets=set_ or [],
        format_=format_,
        executor=executor,
        jobs=jobs,
        until=until,
        cluster_config=cluster_config,
        ray_address=ray_address,
        dry_run=dry_run,
        console=console,
        out=out,
    )


#: The exit code of a run stopped by Ctrl-C (SIGINT), as shells report it (128 + 2).
INTERRUPTED = 130


def _click_errors() -> tuple[type[Exception], ...]:
    """Usage errors: those of the click that newer typer releases vendor, or click's own.
    (Imported here: click is not needed, nor loaded, unless a command line is wrong.)"""
    try:
        from typer._click.exceptions import ClickException
    except ImportError:  # typer < 0.20 uses click itself
        from click import ClickException
    return (ClickException,)


def interrupted(argv: list[str] | None) -> int:
    """Ctrl-C: say so, and how to go on; finished stages are kept and a re-run resumes."""
    command = shlex.join(["endopipe", *(sys.argv[1:] if argv is None else argv)])
    console.print(
        f"[bold red]interrupted[/bold red]: finished stages are kept; "
        f"to resume, run the same command again: {escape(command)}",
        highlight=False,
        soft_wrap=True,
    )
    return INTERRUPTED


def main(argv: list[str] | None = None) -> int:
    """Entry point: one clear line and an exit code for every failure, never a traceback.

    With standalone_mode=False typer returns an exit code instead of exiting; Ctrl-C comes
    back as 130 (typer turns KeyboardInterrupt into Exit(130)), and must not end as 0."""
    try:
        code = app(args=argv, standalone_mode=False)
    except EndopipeError as e:
        console.print(
            f"[bold red]error:[/bold red] {escape(str(e))}", highlight=False, soft_wrap=True
        )
        return e.exit_code
    except typer.Exit as e:
        return e.exit_code
    except typer.Abort:
        console.print("[bold red]aborted[/bold red]")
        return INTERRUPTED
    except _click_errors() as e:
        console.print(f"[bold red]error:[/bold red] {escape(e.format_message())}", soft_wrap=True)
        return e.exit_code
    except KeyboardInterrupt:
        return interrupted(argv)
    except Exception as e:  # an endopipe bug: one line here, the traceback in a log file
        log = Path.home() / ".cache" / "endopipe" / "last_error.log"
        try:
            log.parent.mkdir(parents=True, exist_ok=True)
            log.write_text(traceback.format_exc())
            where = f"; traceback in {log}"
        except OSError:
            where = ""
        console.print(
            f"[bold red]internal error:[/bold red] {type(e).__name__}: {escape(str(e))}{where}",
            highlight=False,
            soft_wrap=True,
        )
        return 1
    if code == INTERRUPTED:
        return interrupted(argv)
    return code if isinstance(code, int) else 0


def entry() -> None:
    sys.exit(main())
