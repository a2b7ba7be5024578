"""`endopipe run workdir/CASE`: a case folder an earlier run made continues where it is, as if
its original input were run again with that workdir and name. A user naturally points `run` at
the folder they see; without this they were told it holds no images."""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import TYPE_CHECKING

from pydantic import ValidationError

from endopipe.commands.cases import prepare_case
from endopipe.pipeline.errors import EndopipeError, InputError
from endopipe.pipeline.stage import CaseInfo

if TYPE_CHECKING:
    from endopipe.pipeline.runner import Pipeline
    from endopipe.pipeline.stage import StageConfig
    from endopipe.stages.io.added import AddedInputs


def reopen_case(
    pipe: Pipeline,
    case_dir: Path,
    configs: dict[str, StageConfig],
    *,
    workdir: Path | None,
    name: str | None,
    intrinsics: Path | None,
    until: str | None,
    from_stage: str | None,
    force: bool,
    added: AddedInputs | None = None,
) -> Path:
    """The case folder, ready for `pipe.run`: its input re-read and case.json refreshed, or,
    when the input is gone, left as it is, provided no stage that reads the input must re-run.

    `workdir` and `name` are what the user gave explicitly (None: not given); another place
    than the folder's own is refused rather than silently ignored. `added` (`--right`,
    `--depth-prior`): given again, it replaces what case.json recorded; else that is kept."""
    folder = case_dir.resolve() if case_dir.name in ("", ".", "..") else case_dir
    info = _case_info(folder)
    _refuse_elsewhere(folder, info, workdir, name)
    source = Path(info.input)
    if source.exists():
        from endopipe.stages.io.added import AddedInputs
        from endopipe.stages.io.sources import FORMATS

        recorded = Path(info.intrinsics_file) if info.intrinsics_file else None
        reader = info.kind if info.kind in FORMATS else None
        if added is None or not added.given:
            added = AddedInputs.of_case(info)
        return prepare_case(
            source, folder.parent, folder.name, intrinsics or recorded, reader, added
        )
    _refuse_without_input(pipe, folder, info, configs, intrinsics, until, from_stage, force)
    return folder


def _case_info(folder: Path) -> CaseInfo:
    try:
        return CaseInfo.load(folder)
    except (OSError, ValueError, ValidationError) as e:
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(
            f"{folder / 'case.json'} is unreadable ({first}); run the case's input again: "
            f"endopipe run INPUT --workdir {shlex.quote(str(folder.parent))} "
            f"--name {shlex.quote(folder.name)}"
        ) from None


def _refuse_elsewhere(folder: Path, info: CaseInfo, workdir: Path | None, name: str | None) -> None:
    given = []
    if workdir is not None and workdir.resolve() != folder.parent.resolve():
        given.append(f"--workdir {shlex.quote(str(workdir))}")
    if name is not None and name != folder.name:
        given.append(f"--name {shlex.quote(name)}")
    if given:
        options = " ".join(given)
        raise EndopipeError(
            f"{folder} is an endopipe case, continued where it is, so {options} does not "
            f"apply: drop it, or start another case from its input: endopipe run "
            f"{shlex.quote(info.input)} {options}"
        )


def _refuse_without_input(
    pipe: Pipeline,
    folder: Path,
    info: CaseInfo,
    configs: dict[str, StageConfig],
    intrinsics: Path | None,
    until: str | None,
    from_stage: str | None,
    force: bool,
) -> None:
    """Without its input a case runs from its cache only: the stages that read the input (those
    with no upstream stage) must be fresh; and when the input's ground truth is gone with it,
    every stage (they evaluate against it)."""
    plan = pipe.plan(folder, info, configs, until, from_stage, force)
    gt_gone = info.gt_dir is not None and not Path(info.gt_dir).exists()
    readers = {s.name for s in pipe.stages if gt_gone or not s.needs}
    stale = [p for p in plan if p.stage in readers and not p.fresh]
    if intrinsics is None and not stale:
        return
    if gt_gone:
        gone, it = f"{info.input} and its ground truth {info.gt_dir} are", "them"
    else:
        gone, it = f"{info.input} is", "it"
    why = "--intrinsics re-reads it" if intrinsics else f"{stale[0].stage} must re-run"
    reason = "" if intrinsics else f" ({stale[0].reason})"
    raise InputError(
        f"case {folder.name}: its input {gone} gone and {why}{reason}; put {it} back, or run "
        "the input from its new place (cached stages are kept when the content is the same): "
        f"endopipe run NEW_PATH --workdir {shlex.quote(str(folder.parent))} "
        f"--name {shlex.quote(folder.name)}"
    )
