"""Package layout only (metadata is in pyproject.toml): the repository keeps each layer in a
folder of its own (the engine in pipeline/, the stages in stages/, the libraries the commands use
in jobs/, recording/, synth/ and export/), installed as endopipe.<folder>, so the distribution
owns one import name, `endopipe`."""

from setuptools import find_packages, setup

LAYERS = ("pipeline", "stages", "jobs", "recording", "synth", "export")
ROOTS = {"endopipe": "endopipe", **{f"endopipe.{folder}": folder for folder in LAYERS}}
packages = [
    f"{name}.{sub}" if sub else name
    for name, folder in ROOTS.items()
    for sub in ["", *find_packages(folder)]
]
setup(
    package_dir=ROOTS,
    packages=packages,
    package_data={
        "endopipe": ["configs/*.yaml"],
        "endopipe.stages.report": ["templates/*.j2", "templates/sections/*.j2", "templates/*.css"],
    },
)
