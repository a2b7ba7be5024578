"""A metric depth a constant apart from a metric truth (Hamlyn rectified01's release depth is
half the depth its own calibration gives) is said beside the scores, with what it means; a
depth within 10% of the truth's scale, or one that is not metric, says nothing."""

from __future__ import annotations

import pytest

from endopipe.stages.depth.metrics_file import DepthMetrics
from endopipe.stages.report.sections.depth import scale_line

SCORES = {"abs_rel": 0.05, "coverage": 0.98}


def metrics(scale: float) -> DepthMetrics:
    return DepthMetrics.model_validate(
        {
            "median_scaled": SCORES,
            "sequence_scaled": {**SCORES, "scale": scale},
            "unscaled": {"abs_rel": abs(1 - scale), "coverage": 0.98},
        }
    )


def test_a_truth_at_half_our_metric_depth_is_said() -> None:
    said = scale_line(metrics(0.508), metric=True)
    assert said is not None and "0.508 times" in said and "calibration or units" in said


@pytest.mark.parametrize("scale", [0.95, 1.0, 1.08])
def test_a_truth_at_our_scale_says_nothing(scale: float) -> None:
    assert scale_line(metrics(scale), metric=True) is None


def test_a_depth_that_is_not_metric_says_nothing() -> None:
    assert scale_line(metrics(0.5), metric=False) is None
