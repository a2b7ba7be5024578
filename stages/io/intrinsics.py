"""Intrinsics files: endopipe's intrinsics.json, and the camera-matrix text files data sets ship.

intrinsics.json is read leniently where the meaning is plain (`"model": "PINHOLE"` or another
of COLMAP's camera model names, `"distortion": "none"`, all-zero coefficients) and strictly
where a value would otherwise be dropped in silence (real coefficients under a name endopipe
does not read). Every problem is one InputError line that names the field.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any, get_args

import cv2
import numpy as np
from pydantic import ValidationError

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.camera.model import LensModel
from endopipe.stages.io.colmap_model import COLMAP_MODELS, LENS_COEFFICIENTS
from endopipe.stages.io.messages import short_reason

LENS_MODELS: tuple[str, ...] = get_args(LensModel)
#: Keys that look like lens distortion but are not endopipe's (`dist` with `model`): refused
#: when they hold a real coefficient, never dropped in silence.
DISTORTION_LIKE = re.compile(r"^(k\d|p\d|d|dist.+|distortion.*|.*coeff.*)$", re.IGNORECASE)
#: COLMAP's parameters that are not distortion coefficients.
COLMAP_PINHOLE_PARAMS = {"f", "fx", "fy", "cx", "cy"}
#: COLMAP's rational terms, which endopipe's radial-tangential lens does not have.
RATIONAL_TERMS = ("k4", "k5", "k6")


def load_intrinsics_file(path: Path) -> Camera:
    """An endopipe intrinsics.json (docs/formats.md) as the Camera it describes."""
    if not path.is_file():
        raise InputError(f"intrinsics file not found: {path}")
    try:
        data = json.loads(path.read_text())
    except OSError as e:
        raise InputError(f"cannot read intrinsics file {path} ({short_reason(e)})") from None
    except ValueError as e:
        raise _not_valid(path, short_reason(e)) from None
    if isinstance(data, dict):
        _refuse_unread_distortion(path, data)
        data = _in_endopipe_terms(path, data)
    try:
        return Camera.model_validate(data)
    except ValidationError as e:
        raise _not_valid(path, _invalid_fields(e)) from None


def read_camera_matrix(path: Path, first_frame: Path, projection: bool = False) -> Camera | None:
    """A data set's camera matrix as text (3x3, row-major; with `projection`, a 3x4 projection
    may stand instead and its 3x3 part is read), at the size of the first frame since the file
    holds none. None when the file is absent."""
    if not path.is_file():
        return None
    what = "3x3 or 3x4 matrix" if projection else "3x3 camera matrix"
    try:
        values = np.array(path.read_text().replace(",", " ").split(), dtype=np.float64)
    except ValueError:
        raise InputError(f"{path} must hold a {what} of numbers") from None
    if values.size not in ((9, 12) if projection else (9,)):
        raise InputError(f"{path} holds {values.size} numbers; expected a {what}")
    K = values.reshape(3, -1)[:, :3]
    image = cv2.imread(str(first_frame), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"cannot read image {first_frame}; remove it or replace it")
    h, w = image.shape[:2]
    return Camera(width=w, height=h, fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2])


def means_no_distortion(value: object) -> bool:
    """Whether a distortion value says "none": the word, null, false, or only zeros."""
    if value is None or value is False:
        return True
    if isinstance(value, str):
        return value.strip().lower() == "none"
    if isinstance(value, int | float) and not isinstance(value, bool):
        return value == 0
    if isinstance(value, list):
        return all(means_no_distortion(v) for v in value)
    if isinstance(value, dict):
        return all(means_no_distortion(v) for v in value.values())
    return False


def _refuse_unread_distortion(path: Path, data: dict[str, Any]) -> None:
    """A real distortion under a name endopipe does not read would be ignored: say so instead."""
    unread = [
        k
        for k, v in data.items()
        if k not in Camera.model_fields and DISTORTION_LIKE.match(k) and not means_no_distortion(v)
    ]
    if unread:
        raise InputError(
            f"intrinsics file {path} has {', '.join(unread)}, which endopipe does not read; give "
            'the lens distortion as "dist" (k1, k2, p1, p2 and k3 for "model": "opencv", or '
            'k1 to k4 for "model": "fisheye")'
        )


def _in_endopipe_terms(path: Path, data: dict[str, Any]) -> dict[str, Any]:
    """`model` as endopipe's lens (any case, or a COLMAP camera model name, whose shorter
    coefficient lists are padded with zeros), and `"dist": "none"` as no coefficients."""
    data = dict(data)
    if isinstance(data.get("dist"), str | bool) and means_no_distortion(data["dist"]):
        data.pop("dist")
    model = data.get("model")
    if not isinstance(model, str):
        return data  # absent (pinhole, or opencv when dist is given), or Camera says what is wrong
    name = model.strip()
    if name.upper() in COLMAP_MODELS:
        data["model"] = COLMAP_MODELS[name.upper()][0]
        if isinstance(data.get("dist"), list):
            data["dist"] = _colmap_dist(path, name.upper(), data["dist"])
    elif name.lower() in LENS_MODELS:
        data["model"] = name.lower()
    else:
        raise InputError(
            f'intrinsics file {path} has "model": {json.dumps(model)}, which endopipe does not '
            f"know; use {', '.join(LENS_MODELS)} or a COLMAP camera model "
            f"({', '.join(COLMAP_MODELS)})"
        )
    return data


def _colmap_dist(path: Path, model: str, dist: list) -> list:
    """`dist` in the order and length of endopipe's lens when it lists exactly the coefficients
    of COLMAP's `model` (SIMPLE_RADIAL: k1); any other list is left for Camera to check."""
    lens, params = COLMAP_MODELS[model]
    names = [p for p in params if p not in COLMAP_PINHOLE_PARAMS]
    numbers = all(isinstance(v, int | float) for v in dist)
    if lens == "pinhole" or len(dist) != len(names) or not numbers:
        return dist
    given = dict(zip(names, dist, strict=True))
    if lens == "opencv" and any(given.get(k) for k in RATIONAL_TERMS):
        raise InputError(
            f"intrinsics file {path}: {model}'s rational terms ({', '.join(RATIONAL_TERMS)}) "
            "are not supported; give them as 0 or use OPENCV"
        )
    wanted = LENS_COEFFICIENTS[lens]
    if lens == "opencv" and "k3" not in given:
        wanted = wanted[:4]
    return [given.get(k, 0.0) for k in wanted]


def _not_valid(path: Path, reason: str) -> InputError:
    return InputError(
        f"intrinsics file {path} is not valid ({reason}); it needs width, height, fx, fy, cx, cy"
    )


def _invalid_fields(e: ValidationError) -> str:
    """Each wrong field by name and value (`fx: must be > 0, got -500`), not pydantic's
    "2 validation errors for Camera"."""
    parts = []
    for err in e.errors(include_url=False):
        where = ".".join(str(x) for x in err["loc"])
        if not where:  # a check across fields (the lens model and its coefficients)
            parts.append(_plain(err["msg"]))
        elif err["type"] == "missing":
            parts.append(f"{where} is missing")
        else:
            parts.append(f"{where}: {_plain(err['msg'])}, got {err['input']!r}")
    return "; ".join(parts)


def _plain(msg: str) -> str:
    """pydantic's wording, shorter: "Input should be greater than 0" -> "must be > 0"."""
    for long, short in (
        ("Input should be greater than or equal to", "must be >="),
        ("Input should be greater than", "must be >"),
        ("Input should be", "must be"),
        ("Value error, ", ""),
    ):
        msg = msg.replace(long, short)
    return msg
