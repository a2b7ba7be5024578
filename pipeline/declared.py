"""A stage read from its source instead of imported, so planning commands start fast.

`endopipe status`, `clean` and `stages` need only a stage's name, needs, version and config. Its
module also imports what `run` uses (torch, cv2, pycolmap: seconds). Those class attributes are
literals in the class body (`name = "nerf"`, `Config = NerfConfig` with its `from ... import`),
so `ast` reads them from the file and only the light config module is imported. Anything not
written that way falls back to importing the module: slower, never wrong.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

#: Class attributes the engine plans with, read as literals.
LITERALS = ("name", "needs", "version", "resumable")


@dataclass(frozen=True)
class DeclaredStage:
    """Stands in for a Stage class: attributes from source, `run` and `view` from the class."""

    module: str
    cls_name: str
    name: str
    needs: tuple[str, ...]
    version: int
    resumable: bool
    config_module: str
    config_name: str
    doc: str

    @cached_property
    def Config(self) -> Any:  # noqa: N802  (the Stage attribute it stands in for)
        return getattr(importlib.import_module(self.config_module), self.config_name)

    def describe(self) -> str:
        return self.doc.strip().splitlines()[0] if self.doc.strip() else ""

    def load(self) -> Any:
        """The Stage class itself, checked against what was read from its source."""
        cls = getattr(importlib.import_module(self.module), self.cls_name)
        read = (self.name, tuple(self.needs), self.version, self.resumable, self.Config)
        real = (cls.name, tuple(cls.needs), cls.version, cls.resumable, cls.Config)
        if read != real:
            raise RuntimeError(f"{self.module}.{self.cls_name}: read {read}, imported {real}")
        return cls

    def view(self, folder: Path) -> Any:
        return self.load().view(folder)

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
    if cls is None:
        return None
    attrs = {"needs": (), "version": 1, "resumable": False}
    config = None
    for node in cls.body:
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
        elif target.id == "Config" and isinstance(node.value, ast.Name):
            config = _imported_from(tree, node.value.id)
    if "name" not in attrs or config is None:
        return None
    return {
        **attrs,
        "needs": tuple(attrs["needs"]),
        "config_module": config[0],
        "config_name": config[1],
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
