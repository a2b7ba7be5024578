"""The command-line options several commands share, spelt once, and the decorator that
declares a command's options from option dataclasses, where their defaults and help live."""

from __future__ import annotations

import dataclasses
import functools
import inspect
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer

DEFAULT_WORKDIR = Path("workdir")
#: Options several commands share, spelt once.
WorkdirOption = Annotated[Path, typer.Option(help="Output root.")]
ConfigOption = Annotated[
    list[str] | None, typer.Option("--config", help="Preset name or YAML file; repeatable.")
]
SetOption = Annotated[list[str] | None, typer.Option("--set", help="stage.key=value; repeatable.")]
BaselineMmOption = Annotated[
    float | None, typer.Option(help="Distance between the two eyes of --right's rig, mm.")
]
Command = TypeVar("Command", bound=Callable[..., Any])


def with_options(**declared: type[Any]) -> Callable[[Command], Command]:
    """Declares a command's options from option dataclasses (`pipeline/options.py`), one option
    per field with its default, help and lower bound, so options several commands share are
    written once, where their defaults live. The command gets each dataclass, built and checked,
    under its keyword (`recording=RecordingOptions(...)`); a value it refuses is a usage error
    naming the option, raised before any work."""

    def decorate(fn: Command) -> Command:
        signature = inspect.signature(fn, eval_str=True)
        kept = [p for p in signature.parameters.values() if p.name not in declared]
        hints = {cls: typing.get_type_hints(cls) for cls in declared.values()}
        added = [
            inspect.Parameter(
                f.name,
                inspect.Parameter.KEYWORD_ONLY,
                default=f.default,
                annotation=Annotated[
                    hints[cls][f.name],
                    typer.Option(help=f.metadata.get("help"), min=f.metadata.get("min")),
                ],
            )
            for cls in declared.values()
            for f in dataclasses.fields(cls)
        ]

        @functools.wraps(fn)
        def command(*args: Any, **kwargs: Any) -> Any:
            built = {}
            for keyword, cls in declared.items():
                values = {f.name: kwargs.pop(f.name) for f in dataclasses.fields(cls)}
                try:
                    built[keyword] = cls(**values)
                except ValueError as e:
                    name, reason = e.args
                    hint = "'--" + name.replace("_", "-") + "'"
                    raise typer.BadParameter(reason, param_hint=hint) from None
            return fn(*args, **kwargs, **built)

        params = kept + added
        command.__signature__ = signature.replace(parameters=params)  # type: ignore[attr-defined]
        command.__annotations__ = {p.name: p.annotation for p in params}
        return command  # type: ignore[return-value]

    return decorate
