"""A recording through windows: its keyframes (the whole input's ingest) cut into overlapping
windows, each window a case of the same stages under `<case>/windows/`, sent to an executor as
batch sends its cases, then joined into one trajectory under `<case>/recording/`.

A window that fails or is doubtful is reported and the others carry on; a re-run does only the
windows with work left (each window is a cached case).
"""

from __future__ import annotations

import copy
import hashlib
import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import BaseModel, Field
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from endopipe.commands.batch.driver import run_cases
from endopipe.commands.batch.rows import CaseRow, CaseTask
from endopipe.commands.recording.frames import pose_every_frame
from endopipe.commands.recording.fuse import one_mesh
from endopipe.commands.recording.join import Joined, join_windows
from endopipe.commands.recording.light_scale import LightScale, correct_drift
from endopipe.commands.recording.one_sfm import pose_once, window_settings
from endopipe.commands.recording.summary import (
    RecordingSummary,
    joined_ate,
    light_line,
    summarise,
)
from endopipe.commands.recording.windows import WindowPlan, plan_windows
from endopipe.pipeline.errors import EndopipeError, InputError
from endopipe.pipeline.executors import ClusterConfig, load_cluster_config
from endopipe.pipeline.runner import Pipeline
from endopipe.pipeline.stage import CaseInfo, StageConfig, write_json

RECORDING_DIR = "recording"
WINDOWS_DIR = "windows"
KEY_FILE = "key.json"
#: Bumped when what the recording writes from the same windows changes.
RECORDING_VERSION = 4


class RecordingOptions(BaseModel):
    """How a long recording is cut and where its windows run."""

    window: int = Field(100, ge=8, description="Keyframes per window.")
    overlap: int = Field(12, ge=3, description="Keyframes shared by neighbouring windows.")
    executor: str = Field("local", description="local | slurm | ray.")
    jobs: int | None = Field(None, ge=1, description="Windows at once.")
    cluster_config: str | None = None
    ray_address: str | None = None
    light_scale: bool = Field(
        True, description="Redraw the joined path for the scale drift the light measures."
    )
    one_sfm_up_to: int = Field(
        200,
        ge=0,
        description="A recording of at most this many keyframes is posed by one SfM and its "
        "lumen fitted once; the windows take their stretch of both (0: each window its own).",
    )


def is_long_input(
    path: Path, intrinsics: Path | None, fmt: str | None, configs: dict[str, StageConfig]
) -> bool:
    """Whether ingest will keep this input's frames by content (a long input): only then is
    its ingest run first, to see whether the keyframes fill more than one window. An input
    that cannot be opened is not (its own run says what is wrong, or goes on from its cache)."""
    from endopipe.stages.ingest.keyframes import keyframes_on
    from endopipe.stages.io.sources import open_input

    try:
        source = open_input(path, intrinsics, format=fmt)
    except InputError:
        return False
    return keyframes_on(configs["ingest"].keyframes, source.frame_count())


def is_recording(pipe: Pipeline, case_dir: Path, options: RecordingOptions) -> bool:
    """Whether ingest kept this input's frames by content and kept more than one window."""
    ingest = pipe.view(case_dir, "ingest")
    return bool(ingest.summary.keyframes) and len(ingest.frames) > options.window


def window_configs(
    configs: dict[str, StageConfig], frames: list[int], shared: Path | None = None
) -> dict[str, dict]:
    """The run's settings for one window: ingest takes exactly its keyframes (already vetted
    for blur, light and motion by the recording's own ingest); with `shared`, the poses and
    lumen of the recording's one SfM."""
    resolved = {name: cfg.model_dump(mode="json") for name, cfg in configs.items()}
    if shared is not None:
        for stage, settings in window_settings(shared).items():
            resolved[stage] = {**resolved[stage], **settings}
    ingest = copy.deepcopy(resolved["ingest"])
    ingest.update(
        frames=frames,
        stride=1,
        max_frames=None,
        start_s=0.0,
        end_s=None,
        drop_duplicates=False,
        drop_blurred=False,
    )
    ingest["keyframes"]["mode"] = "all"
    resolved["ingest"] = ingest
    return resolved


def run_recording(
    pipe: Pipeline,
    case_fn: Callable[[CaseTask], CaseRow],
    case_dir: Path,
    configs: dict[str, StageConfig],
    options: RecordingOptions,
    *,
    until: str | None,
    console: Console,
    from_stage: str | None = None,
    force: bool = False,
) -> RecordingSummary:
    """Cut, run every window, join; writes <case>/recording/ and prints a table."""
    info = CaseInfo.load(case_dir)
    ingest = pipe.view(case_dir, "ingest")
    keyframes = [f.source_index for f in ingest.frames]
    plan = plan_windows(keyframes, options.window, options.overlap)
    windows_dir = (case_dir / WINDOWS_DIR).resolve()
    windows_dir.mkdir(exist_ok=True)
    console.print(
        f"[bold]{escape(info.name)}[/bold]: a recording of {len(keyframes)} keyframes in "
        f"{len(plan.windows)} windows of {len(plan.windows[0])} ({plan.overlap} or more shared), "
        f"{options.executor} executor"
    )
    cluster = (
        load_cluster_config(Path(options.cluster_config) if options.cluster_config else None)
        if options.executor != "local"
        else ClusterConfig()
    )

    def send(tasks: list[CaseTask], on_row: Callable[[CaseRow], None]) -> list[CaseRow]:
        return run_cases(
            options.executor,
            case_fn,
            tasks,
            jobs=options.jobs,
            workdir=windows_dir,
            cluster=cluster,
            ray_address=options.ray_address,
            on_row=on_row,
            note=lambda m: console.print(f"[dim]{escape(m)}[/dim]"),
        )

    shared = None
    if len(keyframes) <= options.one_sfm_up_to and (
        until is None or pipe.index(until) >= pipe.index("poses")
    ):
        whole = CaseTask(
            name=case_dir.name,
            input=info.input,
            reader=info.kind,
            workdir=str(case_dir.parent.resolve()),
            configs={name: cfg.model_dump(mode="json") for name, cfg in configs.items()},
            until="centerline",
            intrinsics=info.intrinsics_file,
            from_stage=from_stage if from_stage in ("ingest", "poses", "centerline") else None,
            force=force,
        )
        shared = pose_once(pipe, case_dir, send([whole], lambda row: None)[0], console)
    tasks = [
        CaseTask(
            name=plan.name(k),
            input=info.input,
            reader=info.kind,
            workdir=str(windows_dir),
            configs=window_configs(configs, frames, shared),
            until=until,
            intrinsics=info.intrinsics_file,
            from_stage=from_stage,
            force=force,
        )
        for k, frames in enumerate(plan.windows)
    ]
    rows = send(tasks, lambda row: _print_window(console, row))
    key = recording_key(pipe, case_dir, plan, configs, until, info, options.light_scale)
    final = case_dir / RECORDING_DIR
    if all(r.status == "ok" and not r.stages_ran for r in rows) and _stored_key(final) == key:
        summary = RecordingSummary.model_validate_json((final / "summary.json").read_text())
        console.print("[dim]recording cached: every window fresh, joined before[/dim]")
        joined = Joined.model_validate_json((final / "trajectory.json").read_text())
        _print_summary(console, summary, joined, case_dir)
        return summary
    poses = [
        _window_poses(pipe, windows_dir / row.case) if row.status == "ok" else None for row in rows
    ]
    joined = join_windows([plan.name(k) for k in range(len(plan.windows))], poses, plan.windows)
    truth = _truth_poses(ingest)
    as_joined = joined
    joined, light = _redraw_for_light(pipe, windows_dir, joined, configs, ingest, options, until)
    summary = summarise(plan, rows, joined, truth)
    summary.one_sfm = shared is not None
    summary.light_scale = light
    if light.applied:
        summary.ate_as_joined_pct = joined_ate(as_joined, truth)[0]
    staging = case_dir / f".{RECORDING_DIR}.tmp"
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir()
    frames = None
    if until is None or pipe.index(until) >= pipe.index("depth"):
        frames = pose_every_frame(
            pipe, info, windows_dir, joined, configs, ingest, staging, summary, console
        )
    mesh = None
    if until is None or pipe.index(until) >= pipe.index("mesh"):
        mesh = one_mesh(pipe, windows_dir, joined, configs, ingest, truth, summary)
    from endopipe.commands.recording.report import write_report

    write_report(
        staging / "report.html",
        info.name,
        summary,
        plan,
        joined,
        [f.source_index for f in ingest.frames],
        ingest.file.dropped_frames,
        frames,
        truth,
    )
    write_json(staging / KEY_FILE, {"key": key})
    _publish(case_dir, staging, plan, joined, summary, mesh)
    _print_summary(console, summary, joined, case_dir)
    return summary


def _redraw_for_light(
    pipe: Pipeline,
    windows_dir: Path,
    joined: Joined,
    configs: dict[str, StageConfig],
    ingest,
    options: RecordingOptions,
    until: str | None,
) -> tuple[Joined, LightScale]:
    """The joined path redrawn for the scale drift the light measures, when asked and the
    windows have depth maps to measure it with."""
    if not options.light_scale:
        return joined, LightScale(applied=False, reason="not asked (--no-light-scale)")
    if until is not None and pipe.index(until) < pipe.index("depth"):
        return joined, LightScale(applied=False, reason="no depth maps yet to measure it with")
    return correct_drift(pipe, windows_dir, joined, ingest, configs["mesh"].min_opacity)


def recording_key(
    pipe: Pipeline,
    case_dir: Path,
    plan: WindowPlan,
    configs: dict[str, StageConfig],
    until: str | None,
    info: CaseInfo,
    light_scale: bool,
) -> str:
    """What recording/ is made from: the input and its ingest (the timeline), the windows'
    keyframes, every window stage's own cache key, the settings the join reads (depth, mesh,
    whether the path is redrawn for the light's scale) and how far the run goes."""
    windows_dir = case_dir / WINDOWS_DIR
    ingest = pipe.manifest(case_dir, "ingest")
    stages = {
        plan.name(k): {
            s.name: (m.key if (m := pipe.manifest(windows_dir / plan.name(k), s.name)) else None)
            for s in pipe.selection(until)
        }
        for k in range(len(plan.windows))
    }
    parts = {
        "version": RECORDING_VERSION,
        "input": info.input_digest,
        "ingest": ingest.key if ingest else None,
        "windows": plan.windows,
        "stages": stages,
        "until": until,
        "light_scale": light_scale,
        "depth": configs["depth"].model_dump(mode="json"),
        "mesh": configs["mesh"].model_dump(mode="json"),
    }
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()


def _stored_key(folder: Path) -> str | None:
    """The key recording/ was written with (None: none, or unreadable: it is made again)."""
    try:
        return json.loads((folder / KEY_FILE).read_text())["key"]
    except (OSError, ValueError, KeyError, TypeError):
        return None


def cameras_by_source(pipe: Pipeline, case_dir: Path) -> dict[int, np.ndarray]:
    """A case's registered cameras (c2w) keyed by source frame: the key a recording's windows,
    and a windowed and a single run of one input, share."""
    ingest = pipe.view(case_dir, "ingest")
    poses = pipe.view(case_dir, "poses")
    return {ingest.frame(i).source_index: c2w for i, c2w in poses.c2w.items()}


def _window_poses(pipe: Pipeline, window_dir: Path) -> dict[int, np.ndarray] | None:
    """A window's registered cameras by source_index (None: no poses to join)."""
    try:
        return cameras_by_source(pipe, window_dir)
    except (OSError, ValueError):
        return None


def _truth_poses(ingest) -> list[np.ndarray] | None:
    """The true c2w of every input frame, by source_index, through the frame -> truth mapping
    (None: no truth, or unreadable: the recording is then not scored)."""
    from endopipe.stages.io.ground_truth import poses_by_frame

    try:
        gt = ingest.ground_truth()
        count = len(gt.poses()) if gt is not None and gt.has_poses() else 0
        every = [_Frame(i, i) for i in range(count)]
        truth = poses_by_frame(gt, every) if count else None
    except InputError:
        return None
    return [truth[i] for i in range(count)] if truth else None


@dataclass(frozen=True)
class _Frame:
    """An input frame as the frame -> truth mapping reads it (index = source_index here)."""

    index: int
    source_index: int


def _publish(
    case_dir: Path,
    tmp: Path,
    plan: WindowPlan,
    joined: Joined,
    summary: RecordingSummary,
    mesh=None,
) -> None:
    """recording/ written whole into the temporary folder `tmp`, then renamed into place."""
    final = case_dir / RECORDING_DIR
    if mesh is not None:
        from endopipe.stages.mesh.view import save_mesh

        save_mesh(tmp, mesh)
    write_json(tmp / "windows.json", plan.model_dump(mode="json"))
    write_json(tmp / "trajectory.json", joined.model_dump(mode="json"))
    write_json(tmp / "summary.json", summary.model_dump(mode="json"))
    shutil.rmtree(final, ignore_errors=True)
    tmp.rename(final)


def _print_window(console: Console, row: CaseRow) -> None:
    if row.status == "ok":
        verdict = " [red]poses doubtful[/red]" if row.pose_verdict == "doubtful" else ""
        ran = f"ran {'+'.join(row.stages_ran)}" if row.stages_ran else "all cached"
        console.print(f"[green]✓[/green] {row.case}  {ran}, {row.this_batch_s:.1f} s{verdict}")
    else:
        console.print(f"[red]✗[/red] {row.case}  {escape(row.reason)}")


def _print_summary(
    console: Console, summary: RecordingSummary, joined: Joined, case_dir: Path
) -> None:
    table = Table(title="windows")
    for col in ("window", "frames", "status", "poses", "junction", "depth AbsRel"):
        table.add_column(col)
    error = {j.b: j for j in joined.junctions}
    for w in summary.windows:
        j = error.get(w.name)
        junction = "" if j is None else (f"{j.error_pct:.2f}%" if j.error_pct is not None else "-")
        if j is not None and not j.joined:
            junction = f"[red]{escape(j.reason)}[/red]"
        absrel = f"{w.depth_abs_rel:.4f}" if w.depth_abs_rel is not None else ""
        table.add_row(w.name, str(w.frames), w.status, w.pose_verdict, junction, absrel)
    console.print(table)
    ate = (
        f"; ATE {summary.ate_percent_of_path:.2f}% of the path over {summary.ate_frames} keyframes"
        if summary.ate_percent_of_path is not None
        else ""
    )
    if summary.depth_abs_rel_all_frames is not None:
        relative = summary.depth_gt_kind == "relative"
        spearman = f"Spearman {summary.depth_spearman_all_frames:.3f}, " if relative else ""
        ate += (
            f"; {summary.frames_posed} of {summary.frames} frames posed, depth {spearman}"
            f"{'SSI-' if relative else ''}AbsRel {summary.depth_abs_rel_all_frames:.4f}, "
            f"coverage {summary.depth_coverage_all_frames:.3f} over "
            f"{summary.depth_frames_scored} frames (keyframes alone "
            f"{summary.depth_abs_rel_keyframes:.4f}; a guess from shading alone "
            f"{summary.brightness_guess_abs_rel:.3f})"
        )
    if summary.chamfer_pct_radius is not None:
        ate += (
            f"; one mesh of {summary.mesh_frames} keyframes: Chamfer "
            f"{summary.chamfer_pct_radius:.2f}% of the radius, {summary.off_seen_pct:.1f}% off "
            "the seen surface"
        )
    colour = "green" if summary.verdict == "ok" else "yellow"
    how = " by one SfM" if summary.one_sfm else ""
    console.print(
        f"[{colour}]{summary.verdict}[/{colour}]: {summary.posed_keyframes} of "
        f"{summary.keyframes} keyframes posed{how} in {summary.segments} segment(s){ate} -> "
        f"{case_dir / RECORDING_DIR}",
        soft_wrap=True,
    )
    for reason in summary.reasons:
        console.print(f"  [yellow]{escape(reason)}[/yellow]", soft_wrap=True)
    if summary.light_scale is not None:
        console.print(f"  [dim]{escape(light_line(summary))}[/dim]", soft_wrap=True)
    if summary.windows and all(w.status != "ok" for w in summary.windows):
        raise EndopipeError("every window of the recording failed; see the table above")
