"""`python -m pipeline ...` is the same as the `endopipe` command."""

from pipeline.cli import entry

entry()
