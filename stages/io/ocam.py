"""Scaramuzza's omnidirectional camera (OCamCalib), as C3VD ships it, and the fisheye of our own
`Camera` fitted to it.

Why a fit and not a new lens model: every ray, projection, export and the synthetic renderer go
through `Camera`'s three models; OpenCV's equidistant fisheye follows a wide scope's lens within
a fraction of a pixel over the field it can hold (rays up to `FIT_MAX_DEG` off the axis), and the
fit's residual says how far it does not.

The model, in OpenCV's pixel axes (x right, y down, pixel centres at integers): a pixel's
offset from the centre (cx, cy) is `stretch` @ (x'', y''), and its ray is (x'', y'', p(rho)),
rho = |(x'', y'')|, p(rho) = a0 + a1 rho + a2 rho^2 + ... (positive: in front of the camera).

Files read (`read_ocam`):
- OCamCalib's own `calib_results.txt` (its `export_data`: the DIRECT polynomial `ss`, the inverse
  one, the centre as row and column from 0, the affine c, d, e, the image height and width). Its
  camera looks down -z in (row, column, z) axes: p = -ss, and the stretch on (x'', y'') is
  [[1, e], [d, c]] (OCamCalib's [[c, d], [e, 1]] acts on (row, column)).
- `key = value` lines, C3VD's registration config (`config.ini`: width, height, cx, cy, a0..a4, c,
  d, e), any `[section]` ignored: C3VD's renderer (DurrLab/C3VD render/Render.cu, Intrinsics.h)
  casts (x'', y'', a0 + a2 rho^2 + a3 rho^3 + a4 rho^4) with stretch glm::mat2(c, d, e, 1),
  column-major: [[c, e], [d, 1]]; a0 is positive.
- one line of 11 or 12 numbers (C3VD's `*_omnidirectional_values.txt`, `camera_intrinsics.txt`):
  width, height, cx, cy, a0, [a1,] a2, a3, a4 and the affine three, named in that order by the
  `*_omnidirectional_format.txt` C3VD ships beside them. Without a format file naming them: c is
  taken as the one near 1 (an aspect ratio), d and e as the other two in file order (each ~0.003
  in C3VD's calibration: their order moves an edge pixel ~1.5 px).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera, project_camera, undistort_normalised

#: The fit covers the pixels whose ray is at most this far off the axis: OpenCV's fisheye maps
#: through tan(theta), which ends at 90 degrees.
FIT_MAX_DEG = 85.0
#: Pixels sampled along each image side for the fit.
FIT_GRID = 96


class OcamLens(BaseModel):
    """An omnidirectional calibration in OpenCV's pixel axes (module docstring)."""

    model_config = ConfigDict(frozen=True)

    width: int = Field(gt=0)
    height: int = Field(gt=0)
    cx: float
    cy: float
    poly: list[float] = Field(min_length=1, description="a0, a1, a2, ...: z of a ray at rho")
    stretch: list[list[float]] = Field(description="2x2: (x'', y'') -> pixel offset")
    source: str = Field("", description="the file and form it was read from")

    def directions(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Unit rays (..., 3) through pixels (u, v)."""
        inv = np.linalg.inv(np.asarray(self.stretch, np.float64))
        off = np.stack([np.asarray(u, np.float64) - self.cx, np.asarray(v, np.float64) - self.cy])
        xy = np.einsum("ij,j...->...i", inv, off)
        rho = np.hypot(xy[..., 0], xy[..., 1])
        z = np.polynomial.polynomial.polyval(rho, self.poly)
        rays = np.concatenate([xy, z[..., None]], -1)
        return rays / np.linalg.norm(rays, axis=-1, keepdims=True)

    def scaled(self, width: int, height: int) -> OcamLens:
        """The same lens seen at another resolution (equal scale on both axes)."""
        s = width / self.width
        if abs(height / self.height - s) > 1e-3:
            raise InputError(
                f"the calibration is for {self.width}x{self.height} frames, not {width}x{height} "
                "(another aspect ratio); give --intrinsics FILE for these frames"
            )
        poly = [a * s ** (1 - i) for i, a in enumerate(self.poly)]  # p_s(s rho) = s p(rho)
        return self.model_copy(
            update={
                "width": width,
                "height": height,
                "cx": (self.cx + 0.5) * s - 0.5,
                "cy": (self.cy + 0.5) * s - 0.5,
                "poly": poly,
            }
        )


class LensFit(BaseModel):
    """The fisheye fitted to an omnidirectional calibration, and how well it follows it."""

    camera: Camera
    rms_px: float = Field(description="RMS reprojection residual over the fitted pixels")
    max_px: float = Field(description="largest residual over the fitted pixels")
    radius_px: float = Field(description="the fitted pixels reach this far from the centre")
    pixel_share: float = Field(description="share of the image's pixels inside the fit")

    def said(self) -> str:
        return (
            f"lens: OpenCV fisheye fitted to the omnidirectional calibration, {self.rms_px:.2f} "
            f"px RMS ({self.max_px:.2f} px at most) over {100 * self.pixel_share:.0f}% of the "
            f"image (rays up to {FIT_MAX_DEG:g} deg, {self.radius_px:.0f} px from the centre)"
        )


def fit_fisheye(lens: OcamLens) -> LensFit:
    """OpenCV's fisheye (fx, fy, cx, cy, k1..k4) that best reprojects the calibration's rays of a
    grid of pixels over the image, least squares in pixels (scipy)."""
    from scipy.optimize import least_squares

    us = np.linspace(0, lens.width - 1, FIT_GRID)
    vs = np.linspace(0, lens.height - 1, max(int(FIT_GRID * lens.height / lens.width), 8))
    u, v = (a.ravel() for a in np.meshgrid(us, vs))
    dirs = lens.directions(u, v)
    inside = dirs[:, 2] > np.cos(np.radians(FIT_MAX_DEG))
    if inside.sum() < 20:
        raise InputError(f"{lens.source}: the calibration gives almost no ray in front of the lens")
    u, v, dirs = u[inside], v[inside], dirs[inside]
    f0 = abs(lens.poly[0])

    def camera(p: np.ndarray) -> Camera:
        fx, fy, cx, cy, *k = (float(x) for x in p)
        return Camera(
            width=lens.width, height=lens.height, fx=fx, fy=fy, cx=cx, cy=cy,
            model="fisheye", dist=k,
        )  # fmt: skip

    def residual(p: np.ndarray) -> np.ndarray:
        uv, _ = project_camera(camera(p), dirs)
        return np.concatenate([uv[:, 0] - u, uv[:, 1] - v])

    start = np.array([f0, f0, lens.cx, lens.cy, 0.0, 0.0, 0.0, 0.0])
    fit = least_squares(residual, start, x_scale="jac", method="lm", max_nfev=4000)
    err = np.hypot(*fit.fun.reshape(2, -1))
    share = _share_inside(lens)
    return LensFit(
        camera=camera(fit.x),
        rms_px=float(np.sqrt(np.mean(err**2))),
        max_px=float(err.max()),
        radius_px=float(np.hypot(u - lens.cx, v - lens.cy).max()),
        pixel_share=share,
    )


def _share_inside(lens: OcamLens) -> float:
    """Share of the image's pixels whose ray is within FIT_MAX_DEG of the axis (every 4th)."""
    u, v = np.meshgrid(np.arange(0, lens.width, 4), np.arange(0, lens.height, 4))
    return float((lens.directions(u, v)[..., 2] > np.cos(np.radians(FIT_MAX_DEG))).mean())


def read_ocam(path: Path) -> OcamLens:
    """An omnidirectional calibration in any of the forms of the module docstring; one
    InputError line naming the file when it is none of them."""
    path = Path(path)
    try:
        text = path.read_text(errors="replace")
    except OSError as e:
        raise InputError(f"cannot read the calibration {path}: {e}") from None
    try:
        if "#polynomial coefficients" in text.lower():
            return _ocamcalib(text, path)
        if re.search(r"^\s*a0\s*=", text, re.MULTILINE | re.IGNORECASE):
            return _key_values(text, path)
        return _one_line(text, path)
    except (ValueError, IndexError, KeyError) as e:
        raise InputError(
            f"cannot read the omnidirectional calibration {path} ({e}); endopipe reads "
            "OCamCalib's calib_results.txt, C3VD's key = value config (width, height, cx, cy, "
            "a0..a4, c, d, e) or its one line of values"
        ) from None


def _numbers(line: str) -> list[float]:
    return [float(t) for t in line.replace(",", " ").split()]


def _ocamcalib(text: str, path: Path) -> OcamLens:
    """OCamCalib's export: five blocks of numbers under '#' headers, in a fixed order."""
    blocks = [_numbers(ln) for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    if len(blocks) < 5:
        raise ValueError(f"{len(blocks)} blocks of numbers, not 5")
    ss_block, _, centre, affine, size = blocks[:5]
    n = int(ss_block[0])
    ss = ss_block[1 : 1 + n]
    if len(ss) != n or len(centre) != 2 or len(affine) != 3 or len(size) != 2:
        raise ValueError("the blocks do not hold ss, invpol, centre, c d e and the image size")
    row, col = centre
    c, d, e = affine
    height, width = (int(round(x)) for x in size)
    return OcamLens(
        width=width,
        height=height,
        cx=col,
        cy=row,
        poly=[-a for a in ss],
        stretch=[[1.0, e], [d, c]],
        source=f"{path} (OCamCalib calib_results.txt)",
    )


def _key_values(text: str, path: Path) -> OcamLens:
    values: dict[str, float] = {}
    for line in text.splitlines():
        line = line.split(";")[0].split("#")[0].strip()
        if "=" in line:
            key, value = line.split("=", 1)
            values[key.strip().lower()] = float(value.split(",")[0])
    need = ("width", "height", "cx", "cy", "a0", "a2", "a3", "a4", "c", "d", "e")
    missing = [k for k in need if k not in values]
    if missing:
        raise KeyError(f"no {', '.join(missing)}")
    a1 = values.get("a1", 0.0)
    return _durrlab(values, a1, f"{path} (key = value, C3VD's config.ini)")


def _one_line(text: str, path: Path) -> OcamLens:
    nums = [
        x for ln in text.splitlines() if ln.strip() and not ln.startswith("#") for x in _numbers(ln)
    ]
    named = _format_names(path, len(nums))
    if named is not None:
        values = dict(zip(named, nums, strict=True))
        return _durrlab(values, values.get("a1", 0.0), f"{path} (named by {named_by(path)})")
    if len(nums) not in (11, 12):
        raise ValueError(f"{len(nums)} numbers, not 11 (or 12 with a1)")
    head = dict(zip(("width", "height", "cx", "cy", "a0"), nums[:5], strict=True))
    a1, rest = (nums[5], nums[6:]) if len(nums) == 12 else (0.0, nums[5:])
    a2, a3, a4, *affine = rest
    ci = int(np.argmin([abs(x - 1.0) for x in affine]))
    if abs(affine[ci] - 1.0) > 0.2:
        raise ValueError(f"none of the affine values {affine} is near 1 (the stretch's c)")
    d, e = (x for i, x in enumerate(affine) if i != ci)
    values = {**head, "a2": a2, "a3": a3, "a4": a4, "c": affine[ci], "d": d, "e": e}
    return _durrlab(values, a1, f"{path} (one line of values; c the affine value near 1)")


def named_by(values: Path) -> str:
    """The format file C3VD ships beside its values file (`X_values.txt` -> `X_format.txt`)."""
    return values.name.replace("values", "format")


def _format_names(values: Path, count: int) -> list[str] | None:
    """The values' names in file order, from the format file beside them (C3VD's
    `*_omnidirectional_format.txt`: the same fields, named); None when there is none, or when its
    names are not the model's or not as many as the values."""
    if "values" not in values.name or not (values.parent / named_by(values)).is_file():
        return None
    text = (values.parent / named_by(values)).read_text(errors="replace")
    names = [re.sub(r"[^a-z0-9]", "", t.lower()) for t in re.split(r"[\s,;]+", text) if t]
    names = [n for n in names if n]
    need = {"width", "height", "cx", "cy", "a0", "a2", "a3", "a4", "c", "d", "e"}
    if len(names) != count or not need <= set(names) or not set(names) <= need | {"a1"}:
        return None
    return names


def named_values(values: dict[str, float], source: str) -> OcamLens:
    """A calibration given by C3VD's field names (Width, Height, cx, cy, a0, [a1,] a2, a3, a4,
    c, d, e; any case), read as its renderer reads them."""
    v = {k.lower(): float(x) for k, x in values.items()}
    return _durrlab(v, v.get("a1", 0.0), source)


def _durrlab(v: dict[str, float], a1: float, source: str) -> OcamLens:
    """C3VD's renderer's model: stretch glm::mat2(c, d, e, 1) (column-major), a0 > 0."""
    poly = [v["a0"], a1, v["a2"], v["a3"], v["a4"]]
    if poly[0] < 0:  # OCamCalib's sign (camera along -z): the same lens looking forward
        poly = [-a for a in poly]
    return OcamLens(
        width=int(round(v["width"])),
        height=int(round(v["height"])),
        cx=v["cx"],
        cy=v["cy"],
        poly=poly,
        stretch=[[v["c"], v["e"]], [v["d"], 1.0]],
        source=source,
    )


def ocam_from_camera(camera: Camera, degree: int = 6) -> OcamLens:
    """The omnidirectional polynomial (a1 = 0, OCamCalib's form) that best holds a `Camera`
    with square pixels: for a synthetic case written with C3VD's calibration file. A pinhole is
    held exactly (p = f)."""
    if abs(camera.fx - camera.fy) > 1e-9 * camera.fx:
        raise ValueError("an omnidirectional calibration here needs square pixels (fx = fy)")
    corner = max(
        np.hypot(u - camera.cx, v - camera.cy)
        for u in (-0.5, camera.width - 0.5)
        for v in (-0.5, camera.height - 0.5)
    )
    rho = np.linspace(1e-3, corner * 1.02, 600)
    xy = np.stack([rho / camera.fx, 0 * rho], -1)  # where the lens puts each image radius
    ideal = undistort_normalised(camera, xy)[:, 0]  # tan(theta)
    z = rho / np.maximum(ideal, 1e-12)
    powers = [0, *range(2, degree + 1)]
    # radii scaled to [0, 1]: in pixels rho^6 outgrows the constant column by 1e13, and the
    # least squares' cut-off dropped the focal length itself
    unit = rho / corner
    A = np.stack([unit**k for k in powers], -1)
    coef, *_ = np.linalg.lstsq(A, z, rcond=None)
    poly = [0.0] * (degree + 1)
    for k, c in zip(powers, coef, strict=True):
        poly[k] = float(c) / corner**k
    return OcamLens(
        width=camera.width,
        height=camera.height,
        cx=camera.cx,
        cy=camera.cy,
        poly=poly,
        stretch=[[1.0, 0.0], [0.0, 1.0]],
        source="fitted to the synthetic camera",
    )


def write_ocamcalib(path: Path, lens: OcamLens, invpol_degree: int = 12) -> None:
    """`lens` as OCamCalib's calib_results.txt (its export_data's layout): for a synthetic case
    written in C3VD's layout. Needs a stretch of OCamCalib's form [[1, e], [d, c]]."""
    (s00, e), (d, c) = lens.stretch
    if abs(s00 - 1.0) > 1e-12:
        raise ValueError("OCamCalib's stretch has 1 at (x, x)")
    ss = [-a for a in lens.poly]
    invpol = _inverse_poly(lens, invpol_degree)
    lines = [
        "#polynomial coefficients for the DIRECT mapping function (ocam_model.ss in MATLAB). "
        "These are used by cam2world",
        "",
        " ".join([str(len(ss)), *(f"{a:e}" for a in ss)]),
        "",
        "#polynomial coefficients for the inverse mapping function (ocam_model.invpol in MATLAB)."
        " These are used by world2cam",
        "",
        " ".join([str(len(invpol)), *(f"{a:f}" for a in invpol)]),
        "",
        '#center: "row" and "column", starting from 0 (C convention)',
        "",
        f"{lens.cy:f} {lens.cx:f}",
        "",
        '#affine parameters "c", "d", "e"',
        "",
        f"{c:f} {d:f} {e:f}",
        "",
        '#image size: "height" and "width"',
        "",
        f"{lens.height} {lens.width}",
        "",
    ]
    Path(path).write_text("\n".join(lines))


def _inverse_poly(lens: OcamLens, degree: int) -> list[float]:
    """OCamCalib's invpol (rho as a polynomial of the ray's elevation atan(z / r)), lowest
    degree first as export_data writes it; endopipe does not read it back."""
    rho = np.linspace(0.0, np.hypot(lens.width, lens.height) / 2, 400)
    theta = np.arctan2(-np.polynomial.polynomial.polyval(rho, lens.poly), np.maximum(rho, 1e-9))
    return [float(a) for a in np.polynomial.polynomial.polyfit(theta, rho, degree)]
