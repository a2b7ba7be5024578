"""C3VD's own scope lens for synthetic cases: the CF-HQ190L calibration C3VD publishes
(Scaramuzza's omnidirectional model at 1350x1080; DurrLab/C3VD python/exampleDataLoader.py),
and the folder it ships in beside the sequences.

The frames are ray-cast through OpenCV's fisheye fitted to it (`ocam.fit_fisheye`: 1.46 px RMS
at 1350x1080, the stretch's skew having no fisheye term), the same fit the C3VD reader makes of
the values file: the case's truth, its written calibration and the pipeline's lens agree.
"""

from __future__ import annotations

from pathlib import Path

from endopipe.stages.camera import Camera
from endopipe.stages.io.ocam import OcamLens, fit_fisheye, named_values

#: The published calibration, its fields by name (a1 = 0: OCamCalib's form).
CF_HQ190L = {
    "Width": 1350,
    "Height": 1080,
    "cx": 678.544839263292,
    "cy": 542.975887548343,
    "a0": 769.243600037458,
    "a2": -0.000812770624150226,
    "a3": 6.25674244578925e-07,
    "a4": -1.19662182144280e-09,
    "c": 0.999986882249990,
    "d": 0.00288273829525059,
    "e": -0.00296316513429569,
}
PARAMS_FOLDER = "cfhq190l_omnidirectional_params"
FORMAT_FILE = "cfhq190l_omnidirectional_format.txt"
VALUES_FILE = "cfhq190l_omnidirectional_values.txt"


def c3vd_lens(width: int, height: int) -> OcamLens:
    """The published calibration at `width` x `height` (its 5:4, or one InputError line)."""
    lens = named_values(CF_HQ190L, "C3VD CF-HQ190L (published)")
    return lens if (width, height) == (lens.width, lens.height) else lens.scaled(width, height)


def c3vd_camera(width: int, height: int) -> Camera:
    """The fisheye the frames are rendered through (module docstring)."""
    return fit_fisheye(c3vd_lens(width, height)).camera


def write_params_folder(folder: Path, width: int, height: int) -> Path:
    """`cfhq190l_omnidirectional_params/` in `folder` as C3VD ships it: a format file naming
    the fields and a values file holding them (at `width` x `height`). Returns the folder."""
    params = Path(folder) / PARAMS_FOLDER
    params.mkdir(parents=True, exist_ok=True)
    s = width / CF_HQ190L["Width"]
    values = dict(CF_HQ190L, Width=width, Height=height)
    values["cx"], values["cy"] = (
        (CF_HQ190L["cx"] + 0.5) * s - 0.5,
        (CF_HQ190L["cy"] + 0.5) * s - 0.5,
    )
    for i, name in enumerate(("a0", "a2", "a3", "a4")):
        values[name] = CF_HQ190L[name] * s ** (1 - (0, 2, 3, 4)[i])
    (params / FORMAT_FILE).write_text(" ".join(values) + "\n")
    (params / VALUES_FILE).write_text(" ".join(f"{v:.15g}" for v in values.values()) + "\n")
    return params
