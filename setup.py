"""Package layout only (metadata is in pyproject.toml): the repository keeps the engine in
pipeline/ and the domain in stages/, installed as endopipe.pipeline and endopipe.stages, so the
distribution owns one import name, `endopipe`."""

from setuptools import find_packages, setup

ROOTS = {"endopipe": "endopipe", "endopipe.pipeline": "pipeline", "endopipe.stages": "stages"}
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
