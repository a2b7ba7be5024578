"""Frames a pixel or two apart (a Hamlyn copy's 418- and 419-pixel-wide frames) are read as one
size, cropped centred, with one line; frames further apart are still refused."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.images import ImageFolderSource


def write_frames(folder: Path, widths: list[int], height: int = 40) -> None:
    folder.mkdir()
    for i, w in enumerate(widths):
        # column x holds the value x: where a crop starts is visible in the pixels
        row = np.arange(w, dtype=np.uint8)
        img = np.repeat(np.repeat(row[None, :, None], height, 0), 3, 2)
        cv2.imwrite(str(folder / f"{i:04d}.png"), img)


def test_frames_a_pixel_apart_read_as_one_size_with_one_line(tmp_path: Path) -> None:
    write_frames(tmp_path / "f", [419, 418, 419, 418])
    k = Camera(width=419, height=40, fx=300.0, fy=300.0, cx=209.0, cy=19.5)
    source = ImageFolderSource(tmp_path / "f", k, None)
    frames = list(source.frames())
    assert {f.rgb.shape for f in frames} == {(40, 418, 3)}
    # centred crop of one extra column: (419 - 418) // 2 = 0 from the left, the last one goes
    assert frames[0].rgb[0, 0, 0] == 0 and frames[0].rgb[0, -1, 0] == 417 % 256
    lines = source.notes  # ingest logs them
    assert len(lines) == 1 and "2 of 4 frames are 419x40" in lines[0] and "418x40" in lines[0]
    assert source.intrinsics is not None
    assert (source.intrinsics.width, source.intrinsics.cx) == (418, 209.0)


def test_principal_point_follows_a_two_pixel_crop(tmp_path: Path) -> None:
    write_frames(tmp_path / "f", [420, 418])
    k = Camera(width=420, height=40, fx=300.0, fy=300.0, cx=210.0, cy=19.5)
    source = ImageFolderSource(tmp_path / "f", k, None)
    frames = list(source.frames())
    assert frames[0].rgb[0, 0, 0] == 1  # one column off each side
    assert source.intrinsics is not None and source.intrinsics.cx == 209.0


def test_frames_ten_pixels_apart_are_refused(tmp_path: Path) -> None:
    write_frames(tmp_path / "f", [418, 428])
    with pytest.raises(InputError, match="images differ in size"):
        ImageFolderSource(tmp_path / "f", None, None)


def test_one_size_says_nothing(tmp_path: Path) -> None:
    write_frames(tmp_path / "f", [418, 418])
    source = ImageFolderSource(tmp_path / "f", None, None)
    assert not source.notes
