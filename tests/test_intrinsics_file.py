"""intrinsics.json as users write it: plain "no distortion" and COLMAP's model names are read,
a real coefficient under a name endopipe does not read is still refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.intrinsics import load_intrinsics_file
from endopipe.stages.io.sources import open_input

BASE = {"width": 96, "height": 80, "fx": 90.0, "fy": 91.0, "cx": 47.5, "cy": 39.5}
PINHOLE = Camera(**BASE)


def intrinsics(tmp_path: Path, **fields: object) -> Path:
    path = tmp_path / "intrinsics.json"
    path.write_text(json.dumps({**BASE, **fields}))
    return path


@pytest.mark.parametrize(
    "fields",
    [
        {"distortion": "none"},
        {"distortion": "None"},
        {"distortion": None},
        {"distortion": [0, 0, 0, 0]},
        {"distortion_coefficients": {"k1": 0.0, "k2": 0.0}},
        {"k1": 0},
        {"D": [0.0, 0.0, 0.0, 0.0, 0.0]},
        {"dist": "none"},
        {"model": "pinhole", "distortion": "none"},
    ],
)
def test_no_distortion_said_another_way_is_a_pinhole(tmp_path: Path, fields: dict) -> None:
    assert load_intrinsics_file(intrinsics(tmp_path, **fields)) == PINHOLE


@pytest.mark.parametrize(
    "fields, unread",
    [
        ({"distortion": [-0.1, 0.01, 0, 0]}, "distortion"),
        ({"k1": 0.05}, "k1"),
        ({"distortion": "plumb_bob"}, "distortion"),
        ({"model": "PINHOLE", "D": [0, 0.2, 0, 0]}, "D"),
    ],
)
def test_a_real_coefficient_under_another_name_is_refused(
    tmp_path: Path, fields: dict, unread: str
) -> None:
    with pytest.raises(InputError) as e:
        load_intrinsics_file(intrinsics(tmp_path, **fields))
    message = str(e.value)
    assert f"has {unread}, which endopipe does not read" in message and '"dist"' in message
    assert "\n" not in message


@pytest.mark.parametrize(
    "fields, model, dist",
    [
        ({"model": "PINHOLE"}, "pinhole", None),
        ({"model": "Pinhole"}, "pinhole", None),
        ({"model": "SIMPLE_PINHOLE"}, "pinhole", None),
        (
            {"model": "OPENCV", "dist": [-0.1, 0.01, 0.001, 0.002]},
            "opencv",
            [-0.1, 0.01, 0.001, 0.002],
        ),
        (
            {"model": "OpenCV", "dist": [-0.1, 0.01, 0, 0, 0.003]},
            "opencv",
            [-0.1, 0.01, 0, 0, 0.003],
        ),
        ({"model": "SIMPLE_RADIAL", "dist": [-0.1]}, "opencv", [-0.1, 0, 0, 0]),
        ({"model": "RADIAL", "dist": [-0.1, 0.01]}, "opencv", [-0.1, 0.01, 0, 0]),
        (
            {"model": "FULL_OPENCV", "dist": [-0.1, 0.01, 0.001, 0.002, 0.003, 0, 0, 0]},
            "opencv",
            [-0.1, 0.01, 0.001, 0.002, 0.003],
        ),
        (
            {"model": "FISHEYE", "dist": [0.1, 0.02, 0.003, 0.0004]},
            "fisheye",
            [0.1, 0.02, 0.003, 0.0004],
        ),
        (
            {"model": "OPENCV_FISHEYE", "dist": [0.1, 0.02, 0.003, 0.0004]},
            "fisheye",
            [0.1, 0.02, 0.003, 0.0004],
        ),
        ({"model": "SIMPLE_RADIAL_FISHEYE", "dist": [0.1]}, "fisheye", [0.1, 0, 0, 0]),
        ({"model": "radial_fisheye", "dist": [0.1, 0.02]}, "fisheye", [0.1, 0.02, 0, 0]),
    ],
)
def test_model_names_in_any_case_and_colmaps_give_endopipes_lens(
    tmp_path: Path, fields: dict, model: str, dist: list | None
) -> None:
    assert load_intrinsics_file(intrinsics(tmp_path, **fields)) == Camera(
        **BASE, model=model, dist=dist
    )


def test_an_unknown_model_name_is_refused_with_the_valid_choices(tmp_path: Path) -> None:
    with pytest.raises(InputError) as e:
        load_intrinsics_file(intrinsics(tmp_path, model="equirectangular"))
    message = str(e.value)
    assert '"model": "equirectangular"' in message and "\n" not in message
    for choice in ("pinhole", "opencv", "fisheye", "PINHOLE", "OPENCV_FISHEYE"):
        assert choice in message


def test_colmaps_rational_terms_are_refused_not_dropped(tmp_path: Path) -> None:
    dist = [-0.1, 0.01, 0, 0, 0, 0.5, 0, 0]
    with pytest.raises(InputError, match="rational terms"):
        load_intrinsics_file(intrinsics(tmp_path, model="FULL_OPENCV", dist=dist))


@pytest.mark.parametrize(
    "text, reason",
    [("{not json", "is not valid ("), (json.dumps({**BASE, "fx": -5}), "fx: must be > 0, got -5")],
)
def test_an_invalid_file_is_one_line_naming_what_is_wrong(
    tmp_path: Path, text: str, reason: str
) -> None:
    path = tmp_path / "intrinsics.json"
    path.write_text(text)
    with pytest.raises(InputError) as e:
        load_intrinsics_file(path)
    assert reason in str(e.value) and "\n" not in str(e.value)


def test_a_case_folder_with_colmaps_spelling_is_read(tmp_path: Path) -> None:
    case = tmp_path / "colon"
    (case / "frames").mkdir(parents=True)
    for i in range(3):
        cv2.imwrite(str(case / "frames" / f"{i:04d}.png"), np.full((80, 96, 3), 60 + i, np.uint8))
    intrinsics(case, model="PINHOLE", distortion="none")
    source = open_input(case)
    assert source.kind == "case" and source.intrinsics == PINHOLE
