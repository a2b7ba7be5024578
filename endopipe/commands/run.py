"""`endopipe run`: what is stale runs, what is fresh is reused; the run's outcome in one line,
and doubtful poses repeated last, where the user looks."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from rich.markup import escape

from endopipe.commands.cases import is_case_dir, prepare_case
from endopipe.commands.terminal import console, out

if TYPE_CHECKING:
    from collections.abc import Callable

    from endopipe.jobs.options import Execution
    from endopipe.jobs.rows import CaseRow, CaseTask
    from endopipe.pipeline.runner import Pipeline, RunRecord
    from endopipe.recording.options import RecordingOptions
    from endopipe.stages.io.added import AddedInputs


def run_case(
    pipe: Pipeline,
    input_path: Path,
    *,
    workdir: Path,
    workdir_given: bool,
    name: str | None,
    config_files: list[str],
    sets: list[str],
    intrinsics: Path | None,
    from_stage: str | None,
    until: str | None,
    force: bool,
    dry_run: bool,
    wait: bool,
    quiet: bool,
    recording: RecordingOptions | None = None,
    execution: Execution | None = None,
    case_fn: Callable[[CaseTask], CaseRow] | None = None,
    added: AddedInputs | None = None,
) -> None:
    """Run INPUT (a video, an image folder, an input case folder, or a case folder an earlier
    run made, which then continues where it is, with its last run's settings) through `pipe`.
    A recording (ingest kept frames by content, more than one window of them) goes on through
    windows with `case_fn`, each window a case, joined into one trajectory. `added`: the right
    views and depth prior given beside the input (`--right`, `--depth-prior`)."""
    from endopipe.commands.resume import reopen_case
    from endopipe.pipeline.config import RUN_CONFIG, load_config
    from endopipe.pipeline.errors import ConfigError

    for stage in (from_stage, until):
        if stage is not None:
            pipe.index(stage)
    if is_case_dir(input_path):
        # Continuing a case continues its last run's settings; --config / --set layer on them.
        recorded = input_path / RUN_CONFIG
        config_files = [str(recorded)] * recorded.is_file() + list(config_files)
    try:
        configs = load_config(pipe.stages, config_files, sets)
    except ConfigError as e:
        if not (is_case_dir(input_path) and (input_path / RUN_CONFIG).is_file()):
            raise
        if _loads(pipe, input_path / RUN_CONFIG):  # the fault is in --config / --set
            raise
        raise ConfigError(
            f"{e}; the case's last-run settings no longer load (another version of endopipe "
            f"wrote them): remove {input_path / RUN_CONFIG} to continue with the defaults and "
            "your --config / --set"
        ) from None
    if is_case_dir(input_path):
        case_dir = reopen_case(
            pipe,
            input_path,
            configs,
            workdir=workdir if workdir_given else None,
            name=name,
            intrinsics=intrinsics,
            added=added,
            until=until,
            from_stage=from_stage,
            force=force,
        )
    else:
        case_dir = prepare_case(input_path, workdir, name, intrinsics, added=added)
    if (
        recording is not None
        and execution is not None
        and case_fn is not None
        and not dry_run
        and until != "ingest"
        and may_be_recording(case_dir, configs)
    ):
        from endopipe.commands.recording import run_recording
        from endopipe.recording.windows import is_recording

        first = pipe.run(
            case_dir,
            configs,
            until="ingest",
            from_stage=from_stage if from_stage == "ingest" else None,
            force=force,
            wait_for_lock=wait,
            console=console,
            quiet=quiet,
        )
        if is_recording(pipe, case_dir, recording):
            print_record(first, case_dir)
            run_recording(
                pipe,
                case_fn,
                case_dir,
                configs,
                recording,
                execution,
                until=until,
                console=console,
                from_stage=from_stage,
                force=force,
            )
            return
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


def may_be_recording(case_dir: Path, configs: dict) -> bool:
    """Whether ingest will keep this case's frames by content (a long input)."""
    from endopipe.pipeline.stage import CaseInfo
    from endopipe.recording.windows import is_long_input

    info = CaseInfo.load(case_dir)
    intrinsics = Path(info.intrinsics_file) if info.intrinsics_file else None
    return is_long_input(Path(info.input), intrinsics, info.kind, configs)


def print_record(record: RunRecord, case_dir: Path) -> None:
    """How many stages ran and how many were reused, and where the outputs are."""
    ran = [s.stage for s in record.stages if s.status == "ran"]
    cached = [s.stage for s in record.stages if s.status == "cached"]
    console.print(
        f"[bold]{record.case}[/bold]: ran {len(ran)} stage(s), {len(cached)} cached, "
        f"{record.wall_s:.1f} s -> {case_dir}"
    )


def print_pose_doubt(pipe: Pipeline, case_dir: Path) -> None:
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


def _loads(pipe: Pipeline, recorded: Path) -> bool:
    """Whether a case's last-run settings load alone (without the user's --config / --set)."""
    from endopipe.pipeline.config import load_config
    from endopipe.pipeline.errors import ConfigError

    try:
        load_config(pipe.stages, [str(recorded)], [])
    except ConfigError:
        return False
    return True
