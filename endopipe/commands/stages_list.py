"""`endopipe stages`: every stage with its config fields, so a user finds the key to --set
without reading the source; or the whole default configuration as YAML."""

from __future__ import annotations

from typing import TYPE_CHECKING

from rich.text import Text

from endopipe.commands.terminal import out

if TYPE_CHECKING:
    from endopipe.pipeline.runner import Pipeline


def print_stages(pipe: Pipeline, as_yaml: bool) -> None:
    """One block per stage: folder, upstream stages, version, description, then its keys."""
    from endopipe.pipeline.config import default_yaml, describe_fields

    if as_yaml:
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
