"""endopipe: monocular endoscopic video to poses, dense depth, a lumen mesh and a report.

The distribution owns this one import name. Its layers, lowest first (import-linter checks them,
`make imports`): `endopipe.pipeline` (the engine, no endoscopy) < `endopipe.stages` (libraries,
then one folder per stage in DAG order) < `endopipe.commands` (each command's body) <
`endopipe.cli` (the composition root: the DAG and the typer commands' options).
In the repository, `pipeline/` and `stages/` are mapped into this package by setuptools.
"""

__version__ = "0.1.0"
