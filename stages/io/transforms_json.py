"""nerfstudio's transforms.json: its one reader and its one writer, lens and axes converted once.

transforms.json (nerfstudio's data format, instant-ngp's before it) holds OpenGL camera-to-world
matrices (x right, y up, z back) and puts pixel centres at +0.5; endopipe's poses are OpenCV's
(x right, y down, z forward) and its pixel centres are integers (docs/formats.md). The lens is
`camera_model` plus coefficients, as nerfstudio's dataparser reads them: a perspective model
(OPENCV, PINHOLE, ...) takes k1, k2, p1, p2 and k3 (OpenCV's radial-tangential lens), and
OPENCV_FISHEYE takes k1..k4 (OpenCV's equidistant fisheye). The intrinsics may sit at the top
level or in every frame; endopipe has one shared camera, so frames that disagree are refused.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np
from pydantic import BaseModel, ConfigDict, ValidationError, field_validator

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.colmap_model import LENS_COEFFICIENTS, PoseSet, camera_to_colmap

#: c2w_opengl = c2w_opencv @ OPENGL_FROM_OPENCV (and back: the matrix is its own inverse).
OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
#: nerfstudio's camera models that are a perspective camera with OpenCV's radial-tangential lens.
PERSPECTIVE_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL")
FISHEYE_MODEL = "OPENCV_FISHEYE"
#: The keys of a camera in transforms.json (top level, or per frame).
CAMERA_KEYS = ("camera_model", "fl_x", "fl_y", "cx", "cy", "w", "h")
COEFFICIENT_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")


class TransformsCamera(BaseModel):
    """The camera keys of transforms.json; unset ones are None (a frame inherits the top
    level's)."""

    model_config = ConfigDict(extra="allow")

    camera_model: str | None = None
    fl_x: float | None = None
    fl_y: float | None = None
    cx: float | None = None
    cy: float | None = None
    w: int | None = None
    h: int | None = None
    k1: float | None = None
    k2: float | None = None
    k3: float | None = None
    k4: float | None = None
    p1: float | None = None
    p2: float | None = None

    def camera_fields(self) -> dict[str, float | int | str]:
        return {
            k: getattr(self, k)
            for k in (*CAMERA_KEYS, *COEFFICIENT_KEYS)
            if getattr(self, k) is not None
        }


class TransformsFrame(TransformsCamera):
    file_path: str
    transform_matrix: list[list[float]]
    mask_path: str | None = None
    depth_file_path: str | None = None

    @field_validator("transform_matrix")
    @classmethod
    def _four_by_four(cls, m: list[list[float]]) -> list[list[float]]:
        shape = np.shape(m)
        if shape == (3, 4):
            return [*m, [0.0, 0.0, 0.0, 1.0]]
        if shape != (4, 4):
            raise ValueError(f"transform_matrix is {shape}, not 4x4 (or 3x4)")
        return m

    def c2w(self) -> np.ndarray:
        """The camera-to-world pose in endopipe's (OpenCV) convention."""
        return np.asarray(self.transform_matrix, dtype=np.float64) @ OPENGL_FROM_OPENCV


class TransformsFile(TransformsCamera):
    """transforms.json, parsed."""

    frames: list[TransformsFrame]

    @classmethod
    def load(cls, path: Path) -> TransformsFile:
        try:
            return cls.model_validate(json.loads(Path(path).read_text()))
        except (OSError, ValueError, ValidationError) as e:
            raise InputError(
                f"cannot read {path} as transforms.json ({_short(e)}); it needs 'frames' with "
                "'file_path' and 'transform_matrix'"
            ) from None

    def c2w(self) -> dict[str, np.ndarray]:
        """OpenCV camera-to-world poses by image file name (the file_path's last part)."""
        return {Path(f.file_path).name: f.c2w() for f in self.frames}

    def camera(self) -> Camera | None:
        """The one shared camera with its lens; None when the file gives no intrinsics."""
        top = self.camera_fields()
        cameras = [top | f.camera_fields() for f in self.frames] or [top]
        if any(c != cameras[0] for c in cameras):
            raise InputError(
                "transforms.json gives its frames different intrinsics; endopipe needs one "
                "shared camera"
            )
        fields = cameras[0]
        if not all(k in fields for k in ("fl_x", "w", "h")):
            return None
        return camera_from_fields(fields)


def camera_from_fields(fields: dict) -> Camera:
    """transforms.json's camera keys as endopipe's `Camera`, its lens included."""
    name = fields.get("camera_model") or "OPENCV"
    value = {k: float(fields.get(k) or 0.0) for k in COEFFICIENT_KEYS}
    if name == FISHEYE_MODEL:
        lens, dist = "fisheye", [value[k] for k in LENS_COEFFICIENTS["fisheye"]]
    elif name in PERSPECTIVE_MODELS:
        if value["k4"]:
            raise InputError("transforms.json: k4 of a perspective camera is not an OpenCV lens")
        lens, dist = "opencv", [value[k] for k in ("k1", "k2", "p1", "p2")]
        if value["k3"]:
            dist.append(value["k3"])
    else:
        known = ", ".join((*PERSPECTIVE_MODELS, FISHEYE_MODEL))
        raise InputError(f"transforms.json: camera_model {name} is not supported; use {known}")
    w, h, fx = int(fields["w"]), int(fields["h"]), float(fields["fl_x"])
    distorted = any(dist)
    return Camera(
        width=w,
        height=h,
        fx=fx,
        fy=float(fields.get("fl_y", fx)),
        cx=float(fields.get("cx", w / 2)) - 0.5,
        cy=float(fields.get("cy", h / 2)) - 0.5,
        model=lens if distorted else "pinhole",
        dist=dist if distorted else None,
    )


def camera_to_fields(camera: Camera) -> dict[str, float | int | str]:
    """endopipe's `Camera` as transforms.json's camera keys: OPENCV (k1, k2, p1, p2, and k3
    when set) or OPENCV_FISHEYE (k1..k4)."""
    fisheye = camera.distorted and camera.model == "fisheye"
    fields: dict[str, float | int | str] = {
        "camera_model": FISHEYE_MODEL if fisheye else "OPENCV",
        "fl_x": camera.fx,
        "fl_y": camera.fy,
        "cx": camera.cx + 0.5,
        "cy": camera.cy + 0.5,
        "w": camera.width,
        "h": camera.height,
    }
    names = LENS_COEFFICIENTS["fisheye"] if fisheye else ("k1", "k2", "p1", "p2")
    fields |= dict.fromkeys(names, 0.0)
    if camera.distorted:
        coefficients = dict(zip(LENS_COEFFICIENTS[camera.model], camera.dist or [], strict=False))
        fields |= {k: float(c) for k, c in coefficients.items() if k in names or c != 0.0}
    return fields


def read_transforms_json(path: Path) -> PoseSet:
    """A nerfstudio / instant-ngp transforms.json as a PoseSet: the camera with its lens (None
    when the file gives no intrinsics) and OpenCV c2w poses by image file name."""
    data = TransformsFile.load(path)
    camera = data.camera()
    model = camera_to_colmap(camera)[0] if camera is not None else None
    return PoseSet(camera, data.c2w(), colmap_model=model)


class TransformsEntry(NamedTuple):
    """One frame to write: paths relative to transforms.json and the OpenCV c2w."""

    file_path: str
    mask_path: str | None
    c2w: np.ndarray
    depth_file_path: str | None = None


def write_transforms_json(
    path: Path,
    camera: Camera,
    frames: Sequence[tuple],
    extra: dict | None = None,
) -> None:
    """Write transforms.json: `frames` are TransformsEntry (file_path, mask_path, c2w OpenCV
    [, depth_file_path]); `extra` adds top-level keys."""
    data: dict = {**camera_to_fields(camera), **(extra or {}), "frames": []}
    for frame in frames:
        entry = TransformsEntry(*frame)
        out: dict = {"file_path": entry.file_path}
        if entry.mask_path is not None:
            out["mask_path"] = entry.mask_path
        if entry.depth_file_path is not None:
            out["depth_file_path"] = entry.depth_file_path
        out["transform_matrix"] = (np.asarray(entry.c2w) @ OPENGL_FROM_OPENCV).tolist()
        data["frames"].append(out)
    Path(path).write_text(json.dumps(data, indent=2) + "\n")


def _short(e: BaseException) -> str:
    if isinstance(e, ValidationError):
        err = e.errors()[0]
        return f"{'.'.join(str(part) for part in err['loc'])}: {err['msg']}"[:160]
    text = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    return text[:160]
