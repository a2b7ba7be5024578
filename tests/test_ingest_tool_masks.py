"""A case folder's tool masks (masks/, 255 = tool): read at the working size, their pixels out
of the usable mask, and a mask of the other polarity refused with one line."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from endopipe.pipeline.errors import InputError
from endopipe.stages.ingest.tools import read_tool_mask, tool_masks_of


def case_with_masks(root: Path, tool_share: float) -> Path:
    case = root / "case"
    (case / "frames").mkdir(parents=True)
    (case / "masks").mkdir()
    (case / "gt").mkdir()
    for i in range(3):
        cv2.imwrite(str(case / "frames" / f"{i:06d}.png"), np.full((48, 64, 3), 120, np.uint8))
    mask = np.zeros((48, 64), np.uint8)
    mask[:, : int(round(64 * tool_share))] = 255
    cv2.imwrite(str(case / "masks" / "000001.png"), mask)
    return case


def test_a_tool_mask_is_read_at_the_working_size_and_only_where_given(tmp_path: Path):
    case = case_with_masks(tmp_path, 0.25)
    folder = tool_masks_of(case / "frames")
    assert folder == case / "masks"
    tool = read_tool_mask(folder, 1, (32, 24))
    assert tool is not None and tool.shape == (24, 32)
    assert tool[:, :8].all() and not tool[:, 8:].any()
    assert read_tool_mask(folder, 0, (32, 24)) is None  # no file: no tool in that frame


def test_a_mask_of_the_other_polarity_is_refused_with_one_line(tmp_path: Path):
    case = case_with_masks(tmp_path, 0.8)
    with pytest.raises(InputError, match="80% of the frame as tool.*255 = tool"):
        read_tool_mask(case / "masks", 1, (64, 48))
