"""The stage contract (docs/architecture.md): a named step with upstream needs, a version and
a typed config.

A stage writes only into `ctx.out` (a temporary folder); the runner publishes it atomically.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, ClassVar, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from endopipe.pipeline.cache import Manifest
from endopipe.pipeline.errors import SummaryMismatch


class StageConfig(BaseModel):
    """Base of every stage's config: unknown keys are errors, assignments are validated."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class Summary(BaseModel):
    """What a stage reports about its run; stored in its manifest. Each stage declares its own
    fields, and its view reads them back as the same model (`read_summary`), so a field that is
    renamed on one side fails loudly instead of blanking a report column."""

    model_config = ConfigDict(extra="forbid")


S = TypeVar("S", bound=Summary)


def read_summary(folder: Path, model: type[S]) -> S:
    """The summary in `folder`'s manifest as the stage's model. A missing manifest or one
    written with other fields is a SummaryMismatch naming the stage and what to do."""
    manifest = Manifest.load(folder)
    if manifest is None:
        raise SummaryMismatch(f"{folder} has no readable manifest.json; re-run its stage")
    try:
        return model.model_validate(manifest.summary)
    except ValidationError as e:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in err['loc']) or '(root)'}: {err['msg']}"
            for err in e.errors()[:3]
        )
        raise SummaryMismatch(
            f"{folder.name}: the {manifest.stage} summary does not match {model.__name__} "
            f"({problems}); re-run with --from {manifest.stage}"
        ) from None


class CaseInfo(BaseModel):
    """`<case>/case.json`: where the input came from, so every stage can find it and its GT."""

    name: str
    input: str
    kind: str  # video | images | case
    input_digest: str
    intrinsics_file: str | None = None
    gt_dir: str | None = None

    @classmethod
    def load(cls, case_dir: Path) -> CaseInfo:
        return cls.model_validate_json((case_dir / "case.json").read_text())


class StageContext:
    """What a running stage may touch: its config, its temporary output folder, its inputs."""

    def __init__(
        self,
        *,
        case_dir: Path,
        out: Path,
        config: StageConfig,
        case: CaseInfo,
        inputs: dict[str, Path],
        resolve_view: Callable[[str, Path], Any],
        console: Console,
        quiet: bool = False,
    ) -> None:
        self.case_dir = case_dir
        self.out = out
        self.config = config
        self.case = case
        self._inputs = inputs
        self._resolve_view = resolve_view
        self.console = console
        self.quiet = quiet

    def input(self, stage_name: str) -> Any:
        """A typed view of an upstream stage's published outputs (only stages in `needs`)."""
        if stage_name not in self._inputs:
            raise KeyError(f"stage input {stage_name!r} is not among this stage's needs")
        return self._resolve_view(stage_name, self._inputs[stage_name])

    def input_dir(self, stage_name: str) -> Path:
        return self._inputs[stage_name]

    def log(self, message: str) -> None:
        if not self.quiet:
            self.console.print(f"    {message}")

    @contextmanager
    def progress(self, description: str, total: int | None) -> Iterator[Callable[..., None]]:
        """A rich progress bar; yields `advance(n=1, **fields)`. Silent when quiet."""
        if self.quiet:
            yield lambda n=1, **_: None
            return
        columns = [
            TextColumn("    [progress.description]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            TextColumn("{task.fields[info]}"),
        ]
        with Progress(*columns, console=self.console, transient=False) as bar:
            task = bar.add_task(description, total=total, info="")

            def advance(n: int = 1, info: str | None = None) -> None:
                bar.update(task, advance=n, **({"info": info} if info is not None else {}))

            yield advance


class Stage:
    """Base class. Subclasses set `name`, `needs`, `version`, `Config`, and implement `run`."""

    name: ClassVar[str]
    needs: ClassVar[tuple[str, ...]] = ()
    version: ClassVar[int] = 1
    Config: ClassVar[type[StageConfig]] = StageConfig
    #: A resumable stage keeps its temporary folder after a crash so a re-run can continue.
    resumable: ClassVar[bool] = False

    def run(self, ctx: StageContext) -> Summary:  # pragma: no cover - abstract
        raise NotImplementedError

    @classmethod
    def view(cls, folder: Path) -> Any:
        """Typed access to this stage's published folder; default: the folder itself."""
        return folder

    @classmethod
    def describe(cls) -> str:
        return (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""


def write_json(path: Path, data: Any) -> None:
    """JSON with a stable layout, so outputs diff cleanly."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, sort_keys=False) + "\n")
