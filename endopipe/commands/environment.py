"""The installed libraries the stages run on, checked when a command that runs them starts: a
pycolmap older than the one pyproject.toml asks for fails deep inside the poses stage (its global
mapper's options differ), so it is refused in one line before any work."""

from __future__ import annotations

import importlib.metadata

from endopipe.pipeline.errors import EndopipeError

#: Distributions whose version range (from endopipe's own metadata) is checked at start-up.
CHECKED = ("pycolmap",)


def check_installed() -> None:
    """Each checked library present and inside the range endopipe's metadata declares."""
    from packaging.requirements import Requirement

    try:
        declared = importlib.metadata.requires("endopipe") or []
    except importlib.metadata.PackageNotFoundError:  # run from a source tree without install
        return
    for text in declared:
        req = Requirement(text)
        if req.name not in CHECKED or req.marker is not None:
            continue
        try:
            found = importlib.metadata.version(req.name)
        except importlib.metadata.PackageNotFoundError:
            raise EndopipeError(
                f"{req.name} is not installed; endopipe needs {req}: pip install '{req}'"
            ) from None
        if not req.specifier.contains(found, prereleases=True):
            raise EndopipeError(
                f"{req.name} {found} is installed; endopipe needs {req}: pip install '{req}'"
            )
