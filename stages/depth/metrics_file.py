"""05_depth/metrics.json (docs/formats.md) as one model: the depth stage writes it through
`DepthMetrics.write`, `DepthView.metrics` reads it back, and the report reads its fields."""

from __future__ import annotations

from pydantic import ConfigDict

from endopipe.stages.metrics.files import MetricsFile
from endopipe.stages.metrics.scores import DepthScores, ProtocolScores


class DepthMetrics(MetricsFile):
    """metrics.json: flat protocol blocks (stages.metrics.depth), per frame, and held-out image
    quality. Blocks are present only when they were computed (no ground truth: none of the
    depth ones); further keys from the metrics library are kept as they are."""

    model_config = ConfigDict(extra="allow", ser_json_inf_nan="constants")

    median_scaled: DepthScores | None = None
    sequence_scaled: DepthScores | None = None
    unscaled: DepthScores | None = None
    affine_invariant: DepthScores | None = None
    frames: int | None = None
    #: per frame: {"index", and a block per protocol}, or for a relative ground truth the
    #: affine-invariant scores flat
    per_frame: list[dict] | None = None
    gt_kind: str | None = None  # "exact" | "pseudo" | "relative"
    #: the share of the field of view on a tool, left out of every depth score (the truth
    #: there is the tool, ours the tissue under it); None: no tool masks
    tool_share_left_out: float | None = None
    #: The radial and brightness guesses (stages.metrics.baselines), scored with the same
    #: protocol blocks on the same pixels as ours: {"radial": {"median_scaled": {...}, ...}}.
    baselines: dict[str, ProtocolScores] | None = None
    heldout_frames: list[int] | None = None
    heldout_psnr: float | None = None
    heldout_ssim: float | None = None
    per_frame_image: dict[str, dict[str, float]] | None = None
    #: the held-out frames predicted by averaging their trained neighbours: {"psnr", "ssim"}
    neighbour_average: dict[str, float] | None = None
    #: ours on the pixels other views agree with ("seen_again") and on the rest ("rest"),
    #: each with the headline protocol block (median-scaled, or affine-invariant)
    by_support: dict[str, DepthScores] | None = None

    def headline(self) -> DepthScores | None:
        """Ours' headline block: median-scaled, or affine-invariant for a relative truth."""
        return self.median_scaled or self.affine_invariant
