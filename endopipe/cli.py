"""The composition root: wires the stages into the DAG and exposes the commands.

Each command here declares its options (the shared ones and the dataclass-declared ones in
cli_options.py) and calls its body in endopipe.commands with the pipeline it needs. Every
failure the user can act on ends as one line on stderr and a non-zero exit code (cli_exit.py).
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from endopipe.cli_exit import run_app
from endopipe.cli_options import (
    DEFAULT_WORKDIR,
    BaselineMmOption,
    ConfigOption,
    SetOption,
    WorkdirOption,
    with_options,
)
from endopipe.commands.cases import prepare_case
from endopipe.commands.terminal import console, out
from endopipe.jobs.options import Execution
from endopipe.recording.options import RecordingOptions

# The stages (torch, cv2) and the command bodies are imported by the commands that use them:
# `endopipe --help` and `status` start in a fraction of a second.
if TYPE_CHECKING:
    from endopipe.jobs.rows import CaseRow, CaseTask
    from endopipe.pipeline.runner import Pipeline
    from endopipe.pipeline.stage import Stage

#: What tests and scripts import from here (prepare_case and the consoles live in commands/).
__all__ = [
    "all_stages",
    "app",
    "batch_case",
    "build_pipeline",
    "console",
    "main",
    "out",
    "planning_pipeline",
    "prepare_case",
]

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="endopipe: monocular endoscopic video -> poses, depth, mesh and an evaluation report.",
)

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
    """The DAG with its stages imported: for commands that run stages, which first check the
    libraries the stages run on (a pycolmap outside the declared range, in one line)."""
    from endopipe.commands.environment import check_installed
    from endopipe.pipeline.runner import Pipeline

    check_installed()

    return Pipeline(all_stages())


def planning_pipeline() -> Pipeline:
    """The DAG read from the stages' source, not imported: plans, configs and folders only,
    so `status`, `clean`, `stages` and `export` start in a fraction of a second."""
    from endopipe.pipeline.declared import declared
    from endopipe.pipeline.runner import Pipeline

    return Pipeline([declared(module, cls) for module, cls in DAG])


@app.command()
@with_options(recording=RecordingOptions, execution=Execution)
def run(
    ctx: typer.Context,
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
    right: Annotated[
        Path | None,
        typer.Option(
            help="Folder of the rectified right eye's frames, matched to the left frames by the "
            "number in their names (a video's frame i: the i-th image); needs --baseline-mm."
        ),
    ] = None,
    baseline_mm: BaselineMmOption = None,
    depth_prior: Annotated[
        Path | None,
        typer.Option(
            help="Folder of depth maps made elsewhere (.npy, 16-bit .png, .tiff), matched by "
            "the number in their names: a relative prior for the field, scored beside ours."
        ),
    ] = None,
    from_stage: Annotated[
        str | None, typer.Option("--from", help="Re-run from this stage.")
    ] = None,
    until: Annotated[str | None, typer.Option(help="Stop after this stage.")] = None,
    force: Annotated[bool, typer.Option(help="Ignore the cache.")] = False,
    dry_run: Annotated[bool, typer.Option(help="Show what would run, run nothing.")] = False,
    wait: Annotated[bool, typer.Option(help="Wait for another run on the same case.")] = False,
    quiet: Annotated[bool, typer.Option(help="No progress output.")] = False,
    *,
    recording: RecordingOptions,
    execution: Execution,
) -> None:
    """Run the pipeline on INPUT: what is stale runs, what is fresh is reused. A long input
    (ingest.keyframes) whose keyframes fill more than one window runs as a recording: windows
    through the executor, joined into one trajectory."""
    from endopipe.commands.run import run_case
    from endopipe.stages.io.added import AddedInputs

    run_case(
        build_pipeline(),
        input,
        workdir=workdir,
        workdir_given=_given(ctx, "workdir"),
        name=name,
        config_files=config or [],
        sets=set_ or [],
        intrinsics=intrinsics,
        from_stage=from_stage,
        until=until,
        force=force,
        dry_run=dry_run,
        wait=wait,
        quiet=quiet,
        recording=recording,
        execution=execution,
        case_fn=batch_case,
        added=AddedInputs(right=right, baseline_mm=baseline_mm, depth_prior=depth_prior),
    )


def _given(ctx: typer.Context, param: str) -> bool:
    """Whether the user typed the option, rather than leaving it at its default."""
    source = ctx.get_parameter_source(param)
    return source is not None and source.name not in ("DEFAULT", "DEFAULT_MAP")


@app.command()
def status(
    case: Annotated[str, typer.Argument(help="Case folder or name under --workdir.")],
    workdir: WorkdirOption = DEFAULT_WORKDIR,
    config: ConfigOption = None,
    set_: SetOption = None,
) -> None:
    """Each stage of CASE: fresh, stale (and why), missing or running. Judged against the
    configuration CASE was last run with; with --config/--set: would that config re-run?"""
    from endopipe.commands.status import show_status

    show_status(planning_pipeline(), case, workdir, config or [], set_ or [])


@app.command()
def clean(
    case: Annotated[str, typer.Argument(help="Case folder or name under --workdir.")],
    workdir: WorkdirOption = DEFAULT_WORKDIR,
    stage: Annotated[
        str | None, typer.Option(help="Remove this stage and its downstream only.")
    ] = None,
) -> None:
    """Remove a case's stage outputs (all, or one stage and what depends on it)."""
    from endopipe.commands.clean import clean_case

    clean_case(planning_pipeline(), case, workdir, stage)


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
    for_: Annotated[
        str | None,
        typer.Option(
            "--for",
            help="endonerf: the loader to write for: endonerf (default) | endogaussian | "
            "deform3dgs (its axes, image size, principal point; depth and poses in one unit).",
        ),
    ] = None,
    endonerf_axes: Annotated[
        str | None,
        typer.Option(
            help="endonerf without --for: rotation columns of poses_bounds.npy: llff (down, "
            "right, back) | opengl (right, up, back) | opencv (right, down, forward); the "
            "camera as it is, depth x depth_scale, translations in the case's units."
        ),
    ] = None,
    resolution: Annotated[
        str,
        typer.Option(
            help="working (the frames the pipeline used) | source (the input's frames at full "
            "size, depth upsampled edge-aware; nerfstudio and endonerf)."
        ),
    ] = "working",
) -> None:
    """Export a case's poses, frames, depth and mesh for nerfstudio, COLMAP, EndoNeRF or PLY."""
    from endopipe.commands.export import export_command

    export_command(
        planning_pipeline(),
        case,
        workdir,
        format_,
        out_dir,
        symlink=symlink,
        endonerf_axes=endonerf_axes,
        target=for_,
        resolution=resolution,
    )


@app.command("stages")
def list_stages(
    yaml_: Annotated[bool, typer.Option("--yaml", help="Print configs/default.yaml.")] = False,
) -> None:
    """Every stage with its config fields, types, defaults and help."""
    from endopipe.commands.stages_list import print_stages

    print_stages(planning_pipeline(), yaml_)


@app.command()
def synth(
    out_dir: Annotated[Path, typer.Argument(metavar="OUT", help="Case folder to write.")],
    seed: int = 0,
    frames: int = 60,
    width: int = 320,
    height: int = 256,
    shape: Annotated[
        str | None,
        typer.Option(
            help="colon | cavity (unset: cavity for the laparoscopic layouts hamlyn, scared and "
            "stereomis, colon otherwise)."
        ),
    ] = None,
    lens: Annotated[
        str,
        typer.Option(
            help="pinhole | barrel (OpenCV k1,k2) | fisheye (OpenCV equidistant) | c3vd (C3VD's "
            "colonoscope: its published calibration; with --layout c3vd its folder as it ships)"
        ),
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
    step_mm: Annotated[
        float, typer.Option(help="Camera travel per frame, mm (a withdrawal at 25 fps: 0.3).")
    ] = 1.0,
    pauses: Annotated[int, typer.Option(help="Times the camera stands still.")] = 0,
    pause_frames: Annotated[int, typer.Option(help="Frames each pause lasts.")] = 25,
    blurred: Annotated[float, typer.Option(help="Fraction of frames with motion blur.")] = 0.0,
    washed_out: Annotated[
        float, typer.Option(help="Fraction of frames washed out by the light.")
    ] = 0.0,
    fps: Annotated[int, typer.Option(help="Frame rate of video.mp4.")] = 15,
    deform: Annotated[
        str,
        typer.Option(
            help="none | breathe (the wall moves out and back) | pull (a patch pulled by a "
            "tool in view; masks/ marks the tool)."
        ),
    ] = "none",
    deform_amplitude: Annotated[
        float | None,
        typer.Option(help="breathe: relative radius change (0.04); pull: mm (4)."),
    ] = None,
    breathe_period: Annotated[float, typer.Option(help="Breathing period, s.")] = 3.0,
    still_camera: Annotated[
        bool, typer.Option("--still-camera", help="Every frame at the path's first pose.")
    ] = False,
    layout: Annotated[
        str,
        typer.Option(
            help="endopipe | endonerf (EndoNeRF's images/ masks/ depth/ poses_bounds.npy "
            "instead of the frames; gt/ kept) | both (EndoNeRF's in OUT/endonerf/) | hamlyn "
            "(rectified: image01/ depth01/ intrinsics.txt) | edam (color/ depth/ intrinsic/)."
        ),
    ] = "endopipe",
    stereo: Annotated[
        bool,
        typer.Option(
            "--stereo",
            help="A right eye 5 mm along +x too (--layout hamlyn: image02/, extrinsics.txt; "
            "scared, stereomis: its right view; endonerf: depth/ matched from it, as EndoNeRF's "
            "own).",
        ),
    ] = False,
) -> None:
    """Write a synthetic lumen case with exact ground truth (depth, poses, mesh, speculars);
    a long recording with pauses and spoiled frames (listed in gt/synth.json) on request; a
    breathing or pulled wall, seen from a still camera if asked."""
    from endopipe.commands.synth import synth_case

    synth_case(
        out_dir,
        seed=seed,
        frames=frames,
        width=width,
        height=height,
        shape=shape,
        lens=lens,
        fov_diag=fov_diag,
        vignetting=vignetting,
        recording={
            "step_mm": step_mm,
            "pauses": pauses,
            "pause_frames": pause_frames,
            "blurred": blurred,
            "washed_out": washed_out,
            "fps": fps,
        },
        motion={
            "deform": deform,
            "deform_amplitude": deform_amplitude,
            "breathe_period_s": breathe_period,
            "still_camera": still_camera,
        },
        layout=layout,
        stereo=stereo,
    )


@app.command()
def demo(
    workdir: WorkdirOption = DEFAULT_WORKDIR,
    frames: int = 24,
) -> None:
    """Synthesise a small colon case and run every stage on it."""
    from endopipe.commands.demo import run_demo

    run_demo(build_pipeline, workdir, frames)


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
    profile: Annotated[
        bool,
        typer.Option(
            help="Each stage's wall time, CPU time and peak memory on each case (default: the "
            "bench colon) and each --input, run from nothing; profile.md and profile.csv."
        ),
    ] = False,
    input_: Annotated[
        list[Path] | None,
        typer.Option("--input", help="With --profile: also a real input (repeatable)."),
    ] = None,
) -> None:
    """The paper's Table 1 on fixed-seed synthetic cases with ablations; CSV and markdown."""
    from endopipe.commands.bench_command import run_bench_command

    run_bench_command(
        build_pipeline,
        workdir,
        quick=quick,
        sets=set_ or [],
        cases=case,
        variants=variant,
        sweep=sweep,
        profile=profile,
        inputs=input_,
    )


# ---------------------------------------------------------------- endopipe batch


def batch_case(task: CaseTask) -> CaseRow:
    """One case of `endopipe batch` with this DAG. Top-level, so executors pickle it by name."""
    from endopipe.jobs.case import process_case

    return process_case(task, build_pipeline, prepare_case)


@app.command()
@with_options(recording=RecordingOptions, execution=Execution)
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
    until: Annotated[str | None, typer.Option(help="Stop each case after this stage.")] = None,
    right: Annotated[
        Path | None,
        typer.Option(
            help="Folder holding one folder per case (named as the case, or its path under "
            "FOLDER) of the rectified right eye's frames; needs --baseline-mm. Hamlyn's "
            "image02/ is found without it."
        ),
    ] = None,
    baseline_mm: BaselineMmOption = None,
    depth_prior: Annotated[
        Path | None,
        typer.Option(
            help="Folder holding one folder per case (named as the case, or its path under "
            "FOLDER) of depth maps made elsewhere: a relative prior, scored beside ours."
        ),
    ] = None,
    dry_run: Annotated[bool, typer.Option(help="List the cases and readers only.")] = False,
    *,
    recording: RecordingOptions,
    execution: Execution,
) -> None:
    """Run every case under FOLDER through the pipeline; write batch.csv and batch.html. A long
    input whose keyframes fill more than one window (a Hamlyn sequence, a whole video) runs as
    a recording: its windows on the executor, joined into one trajectory, one row."""
    from functools import partial

    from endopipe.commands.batch.command import run_batch
    from endopipe.commands.recording import recording_row

    pipe = build_pipeline()
    run_batch(
        pipe,
        batch_case,
        folder,
        workdir,
        config_files=config or [],
        sets=set_ or [],
        format_=format_,
        execution=execution,
        until=until,
        long_case=partial(recording_row, pipe, batch_case, recording, execution, console),
        dry_run=dry_run,
        right=right,
        baseline_mm=baseline_mm,
        depth_prior=depth_prior,
        console=console,
        out=out,
    )


def main(argv: list[str] | None = None) -> int:
    """Entry point: one clear line and an exit code for every failure, never a traceback
    (cli_exit.py)."""
    return run_app(app, argv)


def entry() -> None:
    sys.exit(main())
