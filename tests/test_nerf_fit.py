"""The field's fit in one word (stages/nerf/fit.py): the report's clear word when the field did
not learn its images."""

from __future__ import annotations

from endopipe.stages.nerf.fit import LEARNED_DB, fit_verdict


def test_a_field_under_the_bar_did_not_learn_its_images() -> None:
    v = fit_verdict(21.1, 21.0, 38.3)  # the real Hamlyn clip's rigid field
    assert v.word == "not learned"
    assert "21.1" in v.said and "38.3" in v.said and "SfM points" in v.said


def test_a_field_that_fits_and_renders_held_out_frames_learned() -> None:
    v = fit_verdict(31.7, 31.4, 38.3)
    assert v.word == "learned" and "31.4" in v.said


def test_a_fit_the_held_out_frames_do_not_share_is_named() -> None:
    v = fit_verdict(LEARNED_DB + 5, LEARNED_DB, None)
    assert v.word == "learned, not held out" and "5.0 dB worse" in v.said


def test_no_training_frame_rendered_is_no_word() -> None:
    assert fit_verdict(None, 30.0, 35.0).word == "not measured"
