"""A lumen prior fitted over a longer stretch of the same frames, given to a case instead of its
own (a short recording's one SfM hands its lumen to each window).

A window fits its tube to its own stretch: on C3VD's 75 frames cut in two windows of 45, each
window's tube runs straight along its camera path, 1.7 path lengths wide against the whole
clip's 0.45, and the window's depth scored SSI-AbsRel 0.188 against 0.128 with the whole
clip's tube placed in it. The given prior is placed by the similarity between the cameras both
reconstructions registered (matched by their position in the input), so a window aligned to a
ground truth on its own frames still gets the lumen where its cameras are.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import BaseModel, Field

from endopipe.pipeline.errors import ConfigError
from endopipe.pipeline.stage import write_json
from endopipe.stages.camera import umeyama
from endopipe.stages.centerline.prior import LumenPrior, load_prior, save_prior
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.poses.view import PosesView

PRIOR_FILE = "prior.npz"
CAMERAS_FILE = "cameras.json"


class GivenCameras(BaseModel):
    """cameras.json beside a given prior.npz: the camera centres of the reconstruction it was
    fitted in, by position in the input (source_index)."""

    centres: dict[int, list[float]] = Field(description="source_index -> camera centre.")


def write_given_prior(folder: Path, prior: LumenPrior, centres: dict[int, np.ndarray]) -> None:
    """prior.npz and cameras.json into `folder` (made if missing)."""
    folder.mkdir(parents=True, exist_ok=True)
    save_prior(prior, folder / PRIOR_FILE)
    cams = GivenCameras(centres={int(k): [float(x) for x in c] for k, c in centres.items()})
    write_json(folder / CAMERAS_FILE, cams.model_dump(mode="json"))


def place_given_prior(
    folder: Path, ingest: IngestView, poses: PosesView
) -> tuple[LumenPrior, float]:
    """The prior in `folder` moved into this case's world, and how far apart the shared
    cameras lie after the move (RMS, % of their path)."""
    try:
        given = GivenCameras.model_validate_json((folder / CAMERAS_FILE).read_text())
        prior = load_prior(folder / PRIOR_FILE)
    except (OSError, ValueError) as e:
        raise ConfigError(
            f"centerline.given_prior: {folder} holds no readable prior.npz and cameras.json "
            f"({type(e).__name__}); leave it unset to fit this case's own"
        ) from None
    source_of = {f.index: f.source_index for f in ingest.frames}
    shared = [i for i in poses.registered if source_of[i] in given.centres]
    if len(shared) < 3:
        raise ConfigError(
            f"centerline.given_prior: {folder} shares {len(shared)} registered cameras with this "
            "case; at least 3 are needed to place it"
        )
    src = np.array([given.centres[source_of[i]] for i in shared], np.float64)
    dst = np.array([poses.c2w[i][:3, 3] for i in shared], np.float64)
    s, r, t = umeyama(src, dst)
    moved = s * src @ r.T + t
    path = float(np.linalg.norm(np.diff(dst, axis=0), axis=1).sum())
    rms = float(np.sqrt(np.mean(np.sum((moved - dst) ** 2, axis=1))))
    return prior.moved(s, r, t), 100.0 * rms / max(path, 1e-12)
