"""How well the field learned the images: its fit to frames it trained on, its renders of held-out
frames, both beside the average of a held-out frame's two neighbours (a guess that knows no
geometry), and one word for it.

Why a word: the field's depth is only as good as the images it explains. A field that did not
learn its own training frames (a blur, a smear of the anatomy) has depth that rests on what
trained it besides the images (the SfM points, the stereo, the prior), and the report must say
so rather than let a depth score stand for a field that saw nothing.
"""

from __future__ import annotations

from pydantic import BaseModel, Field

#: A training fit under this (dB, the frames' usable pixels) is a field that did not learn them.
LEARNED_DB = 25.0
#: Held-out renders this much under the training fit (dB): learned, but not seen from elsewhere.
GENERALISE_DB = 3.0


class FitVerdict(BaseModel):
    """The field's fit in one word and one line."""

    word: str = Field(description="learned | learned, not held out | not learned | not measured")
    said: str = Field(description="the judgement with its figures")


def fit_verdict(
    train_psnr: float | None,
    heldout_psnr: float | None,
    neighbour_psnr: float | None,
    rests_on: str = "the SfM points, the stereo and the prior",
) -> FitVerdict:
    """Judge the field's fit from its training fit and held-out PSNR (dB); the neighbour
    average is the baseline the line quotes, `rests_on` what else shaped its depth."""
    if train_psnr is None:
        return FitVerdict(word="not measured", said="no training frame was rendered")
    beside = f", the neighbour average {neighbour_psnr:.1f}" if neighbour_psnr is not None else ""
    held = "none held out"
    if heldout_psnr is not None:
        held = f"held-out {heldout_psnr:.1f} dB{beside}"
    figures = f"training fit {train_psnr:.1f} dB, {held}"
    if train_psnr < LEARNED_DB:
        return FitVerdict(
            word="not learned",
            said=f"the field did not learn its images ({figures}; under {LEARNED_DB:g} dB): its "
            f"depth rests on {rests_on}, not on the images",
        )
    if heldout_psnr is not None and heldout_psnr < train_psnr - GENERALISE_DB:
        return FitVerdict(
            word="learned, not held out",
            said=f"the field learned its training frames but renders the held-out ones "
            f"{train_psnr - heldout_psnr:.1f} dB worse ({figures}): what it learned is not one "
            "scene seen from elsewhere",
        )
    return FitVerdict(word="learned", said=f"the field learned its images ({figures})")
