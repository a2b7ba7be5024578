"""The one camera type: OpenCV intrinsics of one shared camera plus its lens distortion.

Conventions (docs/formats.md): OpenCV axes (x right, y down, z forward); pixel centres at integer
coordinates, the top-left pixel's centre at (0, 0); depth is z-depth along the optical axis.
Distortion models, as OpenCV writes them:
- "pinhole": none;
- "opencv": radial-tangential, `dist` = [k1, k2, p1, p2] or [k1, k2, p1, p2, k3];
- "fisheye": OpenCV's equidistant fisheye, `dist` = [k1, k2, k3, k4].
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

LensModel = Literal["pinhole", "opencv", "fisheye"]
#: How many distortion coefficients each lens model takes (the longest accepted form).
DIST_SIZES: dict[str, tuple[int, ...]] = {"pinhole": (0,), "opencv": (4, 5), "fisheye": (4,)}


class Camera(BaseModel):
    """Intrinsics of one shared camera, in pixels of an image of width x height, and its lens."""

    model_config = ConfigDict(extra="ignore", frozen=True)

    width: int = Field(gt=0, description="image width (px)")
    height: int = Field(gt=0, description="image height (px)")
    fx: float = Field(gt=0, description="focal length along x (px)")
    fy: float = Field(gt=0, description="focal length along y (px)")
    cx: float = Field(description="principal point x (px, pixel-centre convention)")
    cy: float = Field(description="principal point y (px)")
    model: LensModel = Field("pinhole", description="lens distortion model")
    dist: list[float] | None = Field(None, description="distortion coefficients of `model`")

    @model_validator(mode="before")
    @classmethod
    def _model_from_dist(cls, data: object) -> object:
        """intrinsics.json may give `dist` alone (docs/formats.md): five or four numbers are
        OpenCV's radial-tangential model."""
        if isinstance(data, dict) and data.get("dist") and "model" not in data:
            data = {**data, "model": "opencv"}
        return data

    @model_validator(mode="after")
    def _check_dist(self) -> Camera:
        n = len(self.dist or [])
        if self.model == "pinhole" and n and any(self.dist or []):
            raise ValueError("a pinhole camera has no distortion coefficients; set model")
        if self.model != "pinhole" and n not in DIST_SIZES[self.model]:
            sizes = " or ".join(str(s) for s in DIST_SIZES[self.model])
            raise ValueError(f"dist of a {self.model} lens has {sizes} coefficients, not {n}")
        return self

    @property
    def distorted(self) -> bool:
        """Whether rays bend: a fisheye always (with k = 0 it is equidistant, r = f theta, not
        a pinhole), OpenCV's model when a coefficient is not zero."""
        return self.model == "fisheye" or (
            self.model != "pinhole" and any(abs(c) > 0 for c in self.dist or [])
        )

    def coefficients(self) -> np.ndarray:
        """Distortion coefficients as OpenCV wants them (empty for a pinhole)."""
        if not self.distorted:
            return np.zeros(0)
        return np.asarray(self.dist, dtype=np.float64)

    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)

    def scaled(self, width: int, height: int) -> Camera:
        """The same camera seen at another resolution (pixel-centre convention kept; the
        distortion acts on normalised coordinates, so it is unchanged)."""
        return self.zoomed(width / self.width, height / self.height, width, height)

    def zoomed(self, sx: float, sy: float, width: int, height: int) -> Camera:
        """The same camera with `sx`, `sy` times as many pixels along each axis, on an image of
        `width` x `height` (`scaled` when that is this image times them; a calibration stated
        for frames of another size when it is not)."""
        return self.model_copy(
            update={
                "width": width,
                "height": height,
                "fx": self.fx * sx,
                "fy": self.fy * sy,
                "cx": (self.cx + 0.5) * sx - 0.5,
                "cy": (self.cy + 0.5) * sy - 0.5,
            }
        )

    def cropped(self, x0: int, y0: int, width: int, height: int) -> Camera:
        update = {"width": width, "height": height, "cx": self.cx - x0, "cy": self.cy - y0}
        return self.model_copy(update=update)

    def pinhole(self) -> Camera:
        """The same intrinsics without the lens distortion."""
        return self.model_copy(update={"model": "pinhole", "dist": None})

    @classmethod
    def load(cls, path: Path) -> Camera:
        return cls.model_validate(json.loads(Path(path).read_text()))
