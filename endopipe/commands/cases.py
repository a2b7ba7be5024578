"""Case folders: where a run's outputs go, named after its input, and found again by name.

Only the checks are imported eagerly: the readers (cv2, av) load when a case is prepared."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from endopipe.pipeline.errors import EndopipeError

if TYPE_CHECKING:
    from endopipe.stages.io.added import AddedInputs


def case_name_for(input_path: Path) -> str:
    """The case's default name: an input case folder's name (not `video` or `frames`), else the
    file's stem or the folder's name."""
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
    added: AddedInputs | None = None,
) -> Path:
    """Check the input, then create the case folder and its case.json (only then). `added`:
    the right views and depth prior given beside the input, recorded in case.json."""
    from endopipe.pipeline.runner import ensure_writable
    from endopipe.pipeline.stage import CaseInfo, write_json
    from endopipe.stages.io.sources import open_input

    source = open_input(input_path, intrinsics, format=input_format, added=added)
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
        right=str(added.right.expanduser().resolve()) if added and added.right else None,
        baseline_mm=added.baseline_mm if added else None,
        depth_prior=(
            str(added.depth_prior.expanduser().resolve()) if added and added.depth_prior else None
        ),
    )
    case_json = case_dir / "case.json"
    if not case_json.exists() or CaseInfo.load(case_dir) != info:
        tmp = case_dir / ".case.json.tmp"
        write_json(tmp, info.model_dump())
        tmp.replace(case_json)
    return case_dir


def is_case_dir(path: Path) -> bool:
    """A folder an earlier run made (it holds case.json), as opposed to an input."""
    return (path / "case.json").is_file()


def resolve_case(case: str, workdir: Path) -> Path:
    """A case given as its folder or as its name under the workdir."""
    for candidate in (Path(case), workdir / case):
        if is_case_dir(candidate):
            return candidate
    raise EndopipeError(
        f"no endopipe case at {case} (nor {workdir / case}); run `endopipe run INPUT` first"
    )
