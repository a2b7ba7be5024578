"""What a batch's user brings beside each case (`--right RIGHTS --baseline-mm B`, `--depth-prior
PRIORS`): one folder per case under the given folder, found by the case's path under the batch
folder (`PRIORS/rectified01/`) or by its name (`PRIORS/rectified01`, `a__b` for `a/b`).

Why per case: a right eye's frames and a network's depth maps belong to one sequence each; one
folder for the whole batch would pair every case with the first case's maps.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from endopipe.pipeline.errors import InputError
from endopipe.stages.io.cases import FoundCase


@dataclass(frozen=True)
class CaseAdded:
    """One case's own folders (None: none given for it)."""

    right: Path | None = None
    depth_prior: Path | None = None

    def said(self) -> str:
        """What the case runs with, for the batch's table of cases."""
        given = [w for w, p in (("right eye", self.right), ("depth prior", self.depth_prior)) if p]
        return ", ".join(given) or "–"


def case_folder(root: Path, batch_folder: Path, case: FoundCase) -> Path | None:
    """The folder under `root` for `case`: its path under the batch folder, else its name."""
    try:
        rel = case.path.resolve().relative_to(batch_folder.resolve())
    except ValueError:
        rel = None
    for candidate in ([root / rel] if rel is not None and rel.parts else []) + [root / case.name]:
        if candidate.is_dir():
            return candidate
    return None


def per_case_added(
    cases: Sequence[FoundCase],
    batch_folder: Path,
    *,
    right: Path | None,
    depth_prior: Path | None,
    note: Callable[[str], None],
) -> dict[str, CaseAdded]:
    """Each case's right eye and depth prior; a case with no folder of its own runs without
    (one line says which). A root with no folder for any case is refused: it is the wrong one."""
    found: dict[str, dict[str, Path | None]] = {c.name: {} for c in cases}
    for flag, root in (("--right", right), ("--depth-prior", depth_prior)):
        if root is None:
            continue
        if not root.is_dir():
            raise InputError(f"{flag} folder not found: {root}")
        for c in cases:
            found[c.name][flag] = case_folder(root, batch_folder, c)
        missing = [c.name for c in cases if found[c.name][flag] is None]
        if len(missing) == len(cases):
            raise InputError(
                f"{flag} {root} holds no folder named after a case (cases: "
                f"{', '.join(c.name for c in cases)}): give one folder per case, named as the case"
            )
        if missing:
            note(f"{flag}: no folder for {', '.join(missing)} in {root}; they run without")
    return {
        name: CaseAdded(right=f.get("--right"), depth_prior=f.get("--depth-prior"))
        for name, f in found.items()
    }
