"""poses, units: the pose conventions, metrics and file formats (COLMAP models, transforms.json,
cameras.json) and matching image files to frames, without running SfM."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from endopipe.stages.camera import (
    Camera,
    apply_sim3,
    look_at,
    project_camera,
)
from endopipe.stages.ingest.view import FrameEntry, FramesFile, IngestView
from endopipe.stages.io.colmap_model import (
    COLMAP_MODELS,
    PoseSet,
    camera_from_colmap,
    camera_to_colmap,
    read_colmap_model,
    write_text_model,
)
from endopipe.stages.io.transforms_json import read_transforms_json, write_transforms_json
from endopipe.stages.metrics.depth import (
    ate_rmse,
    path_length,
    pose_metrics,
    relative_rotation_error_deg,
)
from endopipe.stages.poses.sources import match_frames
from endopipe.stages.poses.verdict import ranges
from endopipe.stages.poses.view import CamerasFile, PosesView


def test_metrics_are_zero_after_a_similarity_and_see_noise() -> None:
    rng = np.random.default_rng(1)
    gt = {
        i: look_at(
            np.array([0.0, 0.0, 2.0 * i]),
            np.array([0.3, 0.0, 2.0 * i + 10]),
            np.array([0.0, -1.0, 0.0]),
        )
        for i in range(10)
    }
    angle = 0.7
    R = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    est = {i: apply_sim3(0.25, R, np.array([1.0, 2.0, 3.0]), c) for i, c in gt.items()}
    m = pose_metrics(est, gt)
    assert m["ate"] < 1e-9 and m["rre_deg"] < 1e-6 and m["sim3_scale"] == pytest.approx(4.0)
    assert m["gt_path_length"] == pytest.approx(18.0)
    noisy = {i: c.copy() for i, c in est.items()}
    for c in noisy.values():
        c[:3, 3] += rng.normal(0, 0.01, 3)
    assert 0 < pose_metrics(noisy, gt)["ate_percent_of_path"] < 2.0
    centres = np.array([c[:3, 3] for c in gt.values()])
    assert ate_rmse(centres, centres) < 1e-12 and path_length(centres) == pytest.approx(18.0)
    assert relative_rotation_error_deg(list(gt.values()), list(gt.values())) == 0.0


def test_colmap_text_model_and_transforms_json_round_trip(tmp_path: Path) -> None:
    k = Camera(width=320, height=256, fx=150.0, fy=151.0, cx=159.5, cy=127.5)
    poses = {
        f"{i:06d}.png": look_at(
            np.array([i, 0.5 * i, 0.0]), np.array([i, 0.0, 10.0]), np.array([0.0, -1.0, 0.0])
        )
        for i in range(5)
    }
    write_text_model(tmp_path / "sparse", k, poses)
    model = read_colmap_model(tmp_path / "sparse")
    assert model.colmap_model == "PINHOLE" and model.camera == k
    for name, c2w in poses.items():
        assert np.allclose(model.c2w[name], c2w, atol=1e-9)
    frames = [(f"images/{n}", None, c) for n, c in poses.items()]
    write_transforms_json(tmp_path / "transforms.json", k, frames)
    back = read_transforms_json(tmp_path / "transforms.json")
    assert back.camera is not None and back.camera.cx == pytest.approx(k.cx)
    assert not back.camera.distorted
    for name, c2w in poses.items():
        assert np.allclose(back.c2w[name], c2w)
    # known distortion: an OPENCV camera with the same pinhole part, through both files
    distorted = k.model_copy(update={"model": "opencv", "dist": [0.1, 0.01, 0.002, -0.001]})
    model, params = camera_to_colmap(distorted)
    assert model == "OPENCV" and params == [150.0, 151.0, 160.0, 128.0, 0.1, 0.01, 0.002, -0.001]
    write_text_model(tmp_path / "distorted", distorted, poses)
    assert read_colmap_model(tmp_path / "distorted").camera == distorted
    write_transforms_json(tmp_path / "distorted.json", distorted, frames)
    back = read_transforms_json(tmp_path / "distorted.json").camera
    assert back is not None and back.coefficients()[:4].tolist() == distorted.dist
    fisheye = k.model_copy(update={"model": "fisheye", "dist": [0.05, -0.01, 0.002, 0.0]})
    write_transforms_json(tmp_path / "fisheye.json", fisheye, frames)
    assert read_transforms_json(tmp_path / "fisheye.json").camera == fisheye


@pytest.mark.parametrize("model", sorted(COLMAP_MODELS))
def test_colmap_cameras_convert_both_ways_with_their_distortion(model: str) -> None:
    """Every COLMAP model endopipe reads is the same camera as its `Camera`: both project a
    point to the same pixel (pycolmap's own projection), and the params come back unchanged."""
    import pycolmap

    _, names = COLMAP_MODELS[model]
    values = {"f": 150.0, "fx": 150.0, "fy": 152.0, "cx": 161.0, "cy": 127.0}
    values |= {"k1": -0.2, "k2": 0.05, "p1": 0.001, "p2": -0.002, "k3": 0.01, "k4": 0.003}
    if model == "FULL_OPENCV":
        values["k4"] = 0.0  # its rational terms (k4..k6) are not an endopipe lens
    params = [values.get(n, 0.0) for n in names]
    camera = camera_from_colmap(model, 320, 256, params)
    assert camera_to_colmap(camera, model) == (model, params)
    rng = np.random.default_rng(0)
    points = np.c_[rng.uniform(-0.5, 0.5, (50, 2)), np.ones(50)] * rng.uniform(1, 5, (50, 1))
    ours, _ = project_camera(camera, points)
    colmap = pycolmap.Camera(model=model, width=320, height=256, params=params)
    theirs = np.asarray(colmap.img_from_cam(points)) - 0.5  # COLMAP: pixel centres at +0.5
    np.testing.assert_allclose(ours, theirs, atol=1e-6)


def test_a_camera_that_does_not_fit_a_colmap_model_is_refused() -> None:
    k = Camera(width=320, height=256, fx=150.0, fy=151.0, cx=159.5, cy=127.5)
    with pytest.raises(ValueError, match="one focal length"):
        camera_to_colmap(k, "SIMPLE_RADIAL")
    tangential = k.model_copy(update={"fy": 150.0, "model": "opencv", "dist": [0.1, 0, 0.01, 0]})
    with pytest.raises(ValueError, match="no p1"):
        camera_to_colmap(tangential, "RADIAL")
    fisheye = k.model_copy(update={"model": "fisheye", "dist": [0.1, 0, 0, 0]})
    assert camera_to_colmap(fisheye)[0] == "OPENCV_FISHEYE"
    with pytest.raises(ValueError, match="fisheye lens"):
        camera_to_colmap(fisheye, "OPENCV")


def test_cameras_json_holds_one_camera_with_its_lens(tmp_path: Path) -> None:
    """cameras.json keeps the keys docs/formats.md lists; the camera comes back with its lens."""
    k = Camera(width=320, height=256, fx=150.0, fy=150.0, cx=159.5, cy=127.5)
    lens = k.model_copy(update={"model": "opencv", "dist": [-0.2, 0.0, 0.0, 0.0]})
    cams = CamerasFile.build(
        lens, {0: np.eye(4)}, 2, colmap_model="SIMPLE_RADIAL", metric=False, source="colmap"
    )
    data = cams.model_dump(mode="json")
    assert {"width", "height", "fx", "fy", "cx", "cy", "model", "params", "frames"} <= set(data)
    assert data["model"] == "SIMPLE_RADIAL" and data["params"] == [150.0, 160.0, 128.0, -0.2]
    assert (data["fx"], data["cx"]) == (150.0, 159.5)
    (tmp_path / "cameras.json").write_text(json.dumps(data))
    view = PosesView(tmp_path)
    assert view.intrinsics == lens and view.intrinsics.distorted
    assert view.registered == [0]
    with pytest.raises(ValueError, match="not those of"):
        CamerasFile.model_validate({**data, "fx": 151.0})


def test_file_images_are_matched_to_frames_by_number(tmp_path: Path) -> None:
    entries = [
        FrameEntry(index=i, source_index=2 * i, file=f"frames/{i:06d}.png", mask="m.png")
        for i in range(4)
    ]
    frames = FramesFile(frames=entries, width=8, height=8, source={"path": "/no", "kind": "x"})
    (tmp_path / "frames.json").write_text(frames.model_dump_json())
    ingest = IngestView(tmp_path)
    eye = np.eye(4)
    by_number = PoseSet(None, {f"frame_{2 * i + 0:05d}.jpg": eye * (i + 1) for i in range(4)})
    assert sorted(match_frames(by_number, ingest)) == [0, 1, 2, 3]
    by_name = PoseSet(None, {f"{i:06d}.png": eye for i in (1, 3)})
    assert sorted(match_frames(by_name, ingest)) == [1, 3]
    assert ranges([0, 1, 2, 7, 9, 10]) == "0-2, 7, 9-10" and ranges([]) == ""
