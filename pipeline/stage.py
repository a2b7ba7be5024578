"""The stage contract (docs/architecture.md): a named step with upstream needs, a version, and
its types: the config it takes, the summary it returns and the view that reads its folder.

A stage writes only into `ctx.out` (a temporary folder); the runner publishes it atomically.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any, ClassVar, Generic, TypeVar, cast

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
    #: Files the user gave beside the input that ingest reads with it (`--right FOLDER
    #: --baseline-mm B`, `--depth-prior FOLDER`); None: not given.
    right: str | None = None
    baseline_mm: float | None = None
    depth_prior: str | None = None

    @classmethod
    def load(cls, case_dir: Path) -> CaseInfo:
        return cls.model_validate_json((case_dir / "case.json").read_text())


C = TypeVar("C", bound=StageConfig)
V = TypeVar("V")


class StageContext(Generic[C]):
    """What a running stage may touch: its config, its temporary output folder, its inputs.

    Generic in the stage's config (`StageContext[DepthConfig]`), so `ctx.config` has the
    stage's own type; the runner checks that it is an instance of the stage's `Config`.
    """

    def __init__(
        self,
        *,
        case_dir: Path,
        out: Path,
        config: C,
        case: CaseInfo,
        inputs: Mapping[str, Path],
        views: Mapping[str, type[Any]],
        console: Console,
        quiet: bool = False,
    ) -> None:
        """`inputs`: the published folder of each stage in `needs`; `views`: that stage's
        `View` class, which `input` opens the folder with."""
        missing = sorted(set(inputs) - set(views))
        if missing:
            raise ValueError(f"no view class given for the input(s) {', '.join(missing)}")
        self.case_dir = case_dir
        self.out = out
        self.config: C = config
        self.case = case
        self._inputs = dict(inputs)
        self._views = {name: views[name] for name in inputs}
        self._opened: dict[str, Any] = {}
        self.console = console
        self.quiet = quiet

    def input(self, view: type[V]) -> V:
        """The view of the stage in `needs` whose `View` is `view` (or a subclass of it), opened
        on its published folder. Keyed by the view class, not the stage class, so a stage
        imports only its inputs' views, never their stage modules (and what those import)."""
        names = [n for n, cls in self._views.items() if issubclass(cls, view)]
        if len(names) != 1:
            offered = ", ".join(f"{n} ({cls.__name__})" for n, cls in self._views.items())
            why = "several stages it needs have it" if names else "no stage it needs has it"
            raise LookupError(
                f"this stage asked for {view.__name__}, but {why}; its needs: {offered or 'none'}"
            )
        return cast(V, self._open(names[0]))

    def input_by_name(self, stage_name: str) -> Any:
        """The view of upstream stage `stage_name` (one of `needs`), untyped: for a stage that
        reads all its inputs alike (the report). Others use `input(ViewClass)`."""
        self.input_dir(stage_name)
        return self._open(stage_name)

    def input_dir(self, stage_name: str) -> Path:
        """The published folder of upstream stage `stage_name` (one of `needs`)."""
        if stage_name not in self._inputs:
            needs = ", ".join(self._inputs) or "none"
            raise LookupError(f"{stage_name!r} is not among this stage's needs ({needs})")
        return self._inputs[stage_name]

    def _open(self, name: str) -> Any:
        """The view of input `name`, opened once: a view only reads, so one serves every call."""
        if name not in self._opened:
            self._opened[name] = self._views[name](self._inputs[name])
        return self._opened[name]

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


#: The base summary model, by a name the `Stage.Summary` attribute does not shadow.
BaseSummary = Summary


class Stage:
    """Base class. Subclasses set `name`, `needs`, `version`, `Config`, `Summary` and `View` as
    plain class attributes (pipeline/declared.py reads them from the source, without importing
    the stage) and implement `run(ctx)`, which writes only under `ctx.out` and returns an
    instance of `Summary`."""

    name: ClassVar[str]
    needs: ClassVar[tuple[str, ...]] = ()
    version: ClassVar[int] = 1
    Config: ClassVar[type[StageConfig]] = StageConfig
    #: the pydantic model `run` returns (the runner refuses anything else)
    Summary: ClassVar[type[BaseSummary]] = BaseSummary
    #: the only reader of the published folder, `View(folder)`; by default the folder itself
    View: ClassVar[type[Any]] = Path
    #: A resumable stage keeps its temporary folder after a crash so a re-run can continue.
    resumable: ClassVar[bool] = False

    def run(self, ctx: StageContext[Any]) -> BaseSummary:  # pragma: no cover - abstract
        raise NotImplementedError

    @classmethod
    def view(cls, folder: Path) -> Any:
        """This stage's `View` of its published `folder`."""
        return cls.View(folder)

    @classmethod
    def describe(cls) -> str:
        return (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""


def write_json(path: Path, data: Any) -> None:
    """JSON with a stable layout, so outputs diff cleanly."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, sort_keys=False) + "\n")
