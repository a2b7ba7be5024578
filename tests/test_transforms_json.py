"""The one transforms.json reader (stages.io.transforms_json): the lens as nerfstudio reads it,
per-frame intrinsics, 3x4 matrices, and one-line errors for what endopipe cannot take."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.transforms_json import (
    OPENGL_FROM_OPENCV,
    read_transforms_json,
    write_transforms_json,
)

K = Camera(width=64, height=48, fx=50.0, fy=52.0, cx=31.0, cy=24.5)


def write(path: Path, data: dict) -> Path:
    path.write_text(json.dumps(data))
    return path


def frame(name: str, c2w: np.ndarray, **extra) -> dict:
    return {"file_path": f"images/{name}", "transform_matrix": c2w.tolist(), **extra}


def test_the_lens_comes_back_as_written(tmp_path: Path) -> None:
    c2w = np.eye(4)
    c2w[:3, 3] = [1.0, 2.0, 3.0]
    for dist, model in (
        ([-0.3, 0.06, 0.001, -0.002], "opencv"),
        ([0.1, -0.02, 0.003, 0.0], "fisheye"),
    ):
        lens = K.model_copy(update={"model": model, "dist": dist})
        write_transforms_json(tmp_path / "t.json", lens, [("images/a.png", None, c2w)])
        back = read_transforms_json(tmp_path / "t.json")
        assert back.camera == lens and np.allclose(back.c2w["a.png"], c2w)
    with_k3 = K.model_copy(update={"model": "opencv", "dist": [-0.3, 0.06, 0.0, 0.0, 0.01]})
    write_transforms_json(tmp_path / "t.json", with_k3, [("images/a.png", None, c2w)])
    assert read_transforms_json(tmp_path / "t.json").camera == with_k3


def test_per_frame_intrinsics_and_3x4_matrices(tmp_path: Path) -> None:
    """nerfstudio lets every frame carry the camera; one shared camera is read from them."""
    c2w = np.eye(4)
    gl = (c2w @ OPENGL_FROM_OPENCV)[:3]
    cam = {"fl_x": 50.0, "fl_y": 52.0, "cx": 31.5, "cy": 25.0, "w": 64, "h": 48, "k1": -0.1}
    frames = [frame(f"{i}.png", gl, **cam) for i in range(3)]
    back = read_transforms_json(write(tmp_path / "t.json", {"frames": frames}))
    assert back.camera == K.model_copy(update={"model": "opencv", "dist": [-0.1, 0, 0, 0]})
    assert np.allclose(back.c2w["0.png"], c2w) and back.colmap_model == "OPENCV"
    frames[1]["fl_x"] = 51.0
    with pytest.raises(InputError, match="one shared camera"):
        read_transforms_json(write(tmp_path / "t.json", {"frames": frames}))


def test_what_endopipe_cannot_take_is_one_line(tmp_path: Path) -> None:
    base = {"fl_x": 50.0, "w": 64, "h": 48, "frames": [frame("a.png", np.eye(4))]}
    with pytest.raises(InputError, match="EQUIRECTANGULAR is not supported"):
        read_transforms_json(
            write(tmp_path / "t.json", {**base, "camera_model": "EQUIRECTANGULAR"})
        )
    with pytest.raises(InputError, match="k4 of a perspective camera"):
        read_transforms_json(write(tmp_path / "t.json", {**base, "k4": 0.01}))
    bad = {**base, "frames": [frame("a.png", np.eye(3))]}
    with pytest.raises(InputError, match="transform_matrix"):
        read_transforms_json(write(tmp_path / "t.json", bad))
    assert (
        read_transforms_json(write(tmp_path / "t.json", {"frames": base["frames"]})).camera is None
    )
