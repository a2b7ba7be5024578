"""stages/io's modules import each other only at the top and only by public names: an import
inside a function or of a private name is how a cycle between them hides from import-linter."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

IO = Path(__file__).resolve().parents[1] / "stages" / "io"
PACKAGE = "endopipe.stages.io"


def io_imports(tree: ast.AST) -> list[ast.ImportFrom]:
    return [
        node
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(PACKAGE)
    ]


@pytest.mark.parametrize("module", sorted(IO.glob("*.py")), ids=lambda p: p.name)
def test_io_modules_import_each_other_at_the_top_by_public_names(module: Path) -> None:
    tree = ast.parse(module.read_text())
    top = {id(node) for node in tree.body}
    for node in io_imports(tree):
        where = f"{module.name}:{node.lineno}"
        assert id(node) in top, f"{where} imports {node.module} inside a function"
        private = [a.name for a in node.names if a.name.startswith("_")]
        assert not private, f"{where} imports private {', '.join(private)} from {node.module}"
