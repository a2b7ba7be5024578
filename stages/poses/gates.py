"""The poses stage's gates: the checks that stop a run, each in one line with what to try
(too few frames registered; poses judged doubtful when the config says to refuse them)."""

from __future__ import annotations

from endopipe.pipeline.errors import StageFailed
from endopipe.stages.metrics.depth import registered_fraction
from endopipe.stages.poses.config import PosesConfig
from endopipe.stages.poses.verdict import PoseVerdict


def gate(verdict: PoseVerdict, cfg: PosesConfig) -> None:
    """With verdict.on_doubtful=refuse, doubtful poses stop the run with what to try."""
    if verdict.status != "doubtful" or cfg.verdict.on_doubtful != "refuse":
        return
    raise StageFailed(
        f"poses doubtful: {'; '.join(verdict.reasons)}; try known intrinsics (--intrinsics "
        "FILE), a smaller --set ingest.stride, another --set poses.mapper, or --set "
        "poses.verdict.on_doubtful=warn to go on"
    )


def check_registered(registered: int, total: int, cfg: PosesConfig) -> None:
    """The quality gate: one line with the ratio and what to try."""
    frac = registered_fraction(registered, total)
    if frac >= cfg.min_registered and registered >= min(3, total):
        return
    ratio = f"{registered}/{total} frames ({100 * frac:.0f}%) < {100 * cfg.min_registered:.0f}%"
    if cfg.source == "colmap":
        hint = (
            "try a smaller --set ingest.stride, known intrinsics (--intrinsics FILE), or "
            "--set poses.source=file"
        )
    elif cfg.source == "file":
        hint = f"{cfg.file} gives poses for too few frames; check its image names"
    else:
        hint = "the ground truth has too few poses for these frames"
    raise StageFailed(f"registered {ratio}: {hint} (or lower --set poses.min_registered)")
