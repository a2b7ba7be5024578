"""`python -m endopipe ...` is the same as the `endopipe` command."""

from endopipe.cli import entry

entry()
