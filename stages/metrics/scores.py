"""The typed shape of the metrics library's score blocks, for summaries and metrics files.

The functions in `depth.py` return plain dicts (they are array maths); what a stage stores and
what the report and bench read back are these models, so a renamed score fails validation
instead of leaving an empty table cell. NaN is stored as null (JSON has no NaN).
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class DepthScores(BaseModel):
    """One protocol's mean scores over a sequence (docs/formats.md). Which fields are set depends on
    the protocol: the metric ones (median / sequence scaled, unscaled) carry AbsRel..δ³, the
    affine-invariant one AbsRel after a scale and shift, and Spearman's ρ."""

    model_config = ConfigDict(extra="forbid")

    abs_rel: float | None = None
    sq_rel: float | None = None
    rmse: float | None = None
    rmse_log: float | None = None
    delta1: float | None = None
    delta2: float | None = None
    delta3: float | None = None
    spearman: float | None = None
    #: share of the valid ground-truth pixels that got a depth
    coverage: float | None = None
    #: sequence_scaled: the one median-ratio scale of the sequence
    scale: float | None = None


class ProtocolScores(BaseModel):
    """Every protocol computed for one depth source (ours, or a guess); None where it did not
    apply (a relative ground truth has only the affine-invariant block)."""

    model_config = ConfigDict(extra="forbid")

    median_scaled: DepthScores | None = None
    sequence_scaled: DepthScores | None = None
    unscaled: DepthScores | None = None
    affine_invariant: DepthScores | None = None
    frames: int | None = None

    def headline(self) -> DepthScores | None:
        """The block a table leads with: median-scaled, or affine-invariant for a relative
        ground truth."""
        return self.median_scaled or self.affine_invariant
