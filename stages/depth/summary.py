"""The depth stage's summary, one model on both sides: the stage writes it into its manifest,
`DepthView.summary` reads it back, and report, bench and batch read its fields by name."""

from __future__ import annotations

from endopipe.pipeline.stage import Summary
from endopipe.stages.metrics.scores import DepthScores, ProtocolScores


class DepthSummary(Summary):
    frames: int
    units: str
    png_scale: float
    ms_per_frame: float
    bake_s: float
    renderer: str
    gt_kind: str | None = None  # exact | pseudo | relative; None without ground truth
    median_scaled: DepthScores | None = None
    sequence_scaled: DepthScores | None = None
    #: the depth as it is, in millimetres: only when the poses are metric
    unscaled: DepthScores | None = None
    affine_invariant: DepthScores | None = None
    coverage: float | None = None  # share of valid ground-truth pixels that got a depth
    unknown_share: float | None = None  # share of the lens's pixels with no depth
    hazy_share: float | None = None  # ... of which the field spread over no one surface
    #: shares of the lens's pixels whose depth `seen_again_views` other views agree with, whose
    #: depth no other view confirms, and whose depth is inferred: under the frame's own mask,
    #: or past the radius an estimated lens was fitted within (`extrapolated_share` of them)
    seen_again_share: float | None = None
    one_view_share: float | None = None
    inferred_share: float | None = None
    extrapolated_share: float | None = None
    #: the guesses' scores on our pixels (metrics.json `baselines`): radial, brightness
    baselines: dict[str, ProtocolScores] | None = None
    heldout_psnr: float | None = None
    heldout_ssim: float | None = None
    #: the camera stood still: every depth from one viewpoint (relative, no parallax)
    one_viewpoint: bool = False
    #: the ground truth's depth folder when it also supervised the field (EndoNeRF's depth/):
    #: the scores say how closely the field follows it, not how right it is
    truth_supervised: str | None = None
    #: what the depth maps are held to (depth.anchor): "stereo", "SfM points" or None, and
    #: the shares of the depth pixels measured (pasted) and corrected, means over the frames
    anchored_to: str | None = None
    measured_share: float | None = None
    corrected_share: float | None = None
    #: the held-out frames predicted by averaging their trained neighbours (no geometry)
    neighbour_psnr: float | None = None
    neighbour_ssim: float | None = None

    def scores(self) -> ProtocolScores:
        """Our protocol blocks in the shape the guesses' have, to show them side by side."""
        return ProtocolScores(
            median_scaled=self.median_scaled,
            sequence_scaled=self.sequence_scaled,
            unscaled=self.unscaled,
            affine_invariant=self.affine_invariant,
            frames=self.frames,
        )
