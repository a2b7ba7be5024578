"""A stage read from its source instead of imported, so planning commands start fast.

`endopipe status`, `clean` and `stages` need only a stage's name, needs, version and config. Its
module also imports what `run` uses (torch, cv2, pycolmap: seconds). Those class attributes are
literals in the class body (`name = "nerf"`, `Config = NerfConfig`, `Summary = NerfSummary`,
`View = NerfView`, each with its `from ... import`), so `ast` reads them from the file and only
the module a caller asks for is imported: the config's to plan, the view's to read a folder.
Anything not written that way falls back to importing the module: slower, never wrong.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

from endopipe.pipeline.stage import Stage

#: Class attributes the engine plans with, read as literals.
LITERALS = ("name", "needs", "version", "resumable")
#: Class attributes that name a class imported at the module's top (`Config = NerfConfig`);
#: Summary and View may be left out (the base Stage's then apply).
IMPORTED = ("Config", "Summary", "View")


@dataclass(frozen=True)
class DeclaredStage:
    """Stands in for a Stage class: attributes from source, `run` from the class. `Config`,
    `Summary` and `View` import only their own modules."""

    module: str
    cls_name: str
    name: str
    needs: tuple[str, ...]
    version: int
    resumable: bool
    #: (attribute, module, name) of each class attribute read as an import; one left out is
    #: the base Stage's
    imported: tuple[tuple[str, str, str], ...]
    doc: str

    def _imported(self, attr: str) -> Any:
        """The class attribute `attr` names, importing only the module it comes from."""
        for read, module, name in self.imported:
            if read == attr:
                return getattr(importlib.import_module(module), name)
        return getattr(Stage, attr)

    @cached_property
    def Config(self) -> Any:  # noqa: N802  (the Stage attribute it stands in for)
        return self._imported("Config")

    @cached_property
    def Summary(self) -> Any:  # noqa: N802
        return self._imported("Summary")

    @cached_property
    def View(self) -> Any:  # noqa: N802
        return self._imported("View")

    def describe(self) -> str:
        return self.doc.strip().splitlines()[0] if self.doc.strip() else ""

    def load(self) -> Any:
        """The Stage class itself, checked against what was read from its source."""
        cls = getattr(importlib.import_module(self.module), self.cls_name)
        attrs = ("name", "needs", "version", "resumable", *IMPORTED)
        read = tuple(getattr(self, a) for a in attrs)
        real = tuple(getattr(cls, a) for a in attrs)
        if read != real:
            raise RuntimeError(f"{self.module}.{self.cls_name}: read {read}, imported {real}")
        return cls

    def view(self, folder: Path) -> Any:
        """The stage's View of `folder`, without importing the stage's module."""
        return self.View(folder)

    def __call__(self) -> Any:
        return self.load()()


def declared(module: str, cls_name: str) -> Any:
    """`module.cls_name` as a DeclaredStage, or the imported class when its source is not plain."""
    source = _source_of(module)
    found = _read(source, cls_name) if source is not None else None
    if found is None:
        return getattr(importlib.import_module(module), cls_name)
    return DeclaredStage(module=module, cls_name=cls_name, **found)


def _source_of(module: str) -> str | None:
    spec = importlib.util.find_spec(module)
    if spec is None or spec.origin is None or not spec.origin.endswith(".py"):
        return None
    return Path(spec.origin).read_text()


def _read(source: str, cls_name: str) -> dict[str, Any] | None:
    tree = ast.parse(source)
    cls = next((n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == cls_name), None)
    if cls is None or [getattr(b, "id", None) for b in cls.bases] != ["Stage"]:
        return None  # absent, or attributes it may inherit from a class between it and Stage
    attrs: dict[str, Any] = {"needs": (), "version": 1, "resumable": False}
    imported: dict[str, tuple[str, str]] = {}  # attribute -> (module, name)
    for node in cls.body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.name == "view":
            return None  # a view of its own: only the class knows it
        if not (isinstance(node, ast.Assign) and len(node.targets) == 1):
            continue
        target = node.targets[0]
        if not isinstance(target, ast.Name):
            continue
        if target.id in LITERALS:
            try:
                attrs[target.id] = ast.literal_eval(node.value)
            except ValueError:
                return None
        elif target.id in IMPORTED:
            value = node.value
            found = _imported_from(tree, value.id) if isinstance(value, ast.Name) else None
            if found is None:
                return None
            imported[target.id] = found
    if "name" not in attrs or "Config" not in imported:
        return None
    return {
        **attrs,
        "needs": tuple(attrs["needs"]),
        "imported": tuple((attr, *where) for attr, where in imported.items()),
        "doc": ast.get_docstring(cls) or "",
    }


def _imported_from(tree: ast.Module, name: str) -> tuple[str, str] | None:
    """Where `from M import X [as name]` at the module's top level takes `name` from."""
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for alias in node.names:
                if (alias.asname or alias.name) == name:
                    return node.module, alias.name
    return None
