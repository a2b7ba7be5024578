"""A calibration checked against the frames it is given for.

Releases state calibrations for another image size than the frames users download (Hamlyn's
rectified01 states 320x240; its public frames are those images upsampled to 640x480). Read as
the frames' own, such a calibration puts the principal point a quarter of the way across the
image and the focal length at half the true one: metric depth twice off, in silence. The
principal point says so: a lens's optical axis meets the sensor near its centre, so a principal
point far from the centre that lands on it when the calibration is taken for an integer factor
smaller (or larger) frames is a calibration stated for that size, and is rescaled aloud; one
that lands nowhere near the centre at any such size is refused.
"""

from __future__ import annotations

from dataclasses import dataclass

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera

#: A principal point further than this share of the image from its centre (on either axis) is
#: not the frames' own (real scopes: within a few percent).
OFF_CENTRE = 0.15
#: Rescaled by a factor, it must land within this share of the centre on both axes.
ON_CENTRE = 0.08
#: The sizes a calibration may have been stated for: the frames' own times these factors.
FACTORS = (1 / 2, 1 / 3, 1 / 4, 2.0, 3.0, 4.0)


@dataclass(frozen=True)
class CalibrationFit:
    """The camera for the frames, and one line on what was found (None: it fits as given)."""

    camera: Camera
    said: str | None = None


def off_centre(camera: Camera) -> float:
    """The principal point's largest offset from the image centre, as a share of the image."""
    return max(
        abs((camera.cx + 0.5) / camera.width - 0.5), abs((camera.cy + 0.5) / camera.height - 0.5)
    )


def fit_to_frames(camera: Camera, source: str) -> CalibrationFit:
    """`camera` as read for the frames' size (width, height = the frames'), checked: as given,
    rescaled from the size it was stated for (said), or refused (InputError, one line)."""
    share = off_centre(camera)
    if share <= OFF_CENTRE:
        return CalibrationFit(camera)
    w, h = camera.width, camera.height
    for factor in FACTORS:
        # its numbers taken as a calibration of frames `factor` times the size, brought here
        mended = camera.zoomed(1.0 / factor, 1.0 / factor, w, h)
        if off_centre(mended) <= ON_CENTRE:
            sw, sh = round(w * factor), round(h * factor)
            return CalibrationFit(
                mended,
                f"{source}: the calibration puts the principal point ({camera.cx:.1f}, "
                f"{camera.cy:.1f}) {share:.0%} of the image off the centre of the {w}x{h} frames; "
                f"it is one for {sw}x{sh} frames (there the point is central): rescaled to "
                f"{w}x{h} (fx {mended.fx:.1f}, cx {mended.cx:.1f}, cy {mended.cy:.1f})",
            )
    inside = 0 <= camera.cx < w and 0 <= camera.cy < h
    if not inside or share > 0.35:
        raise InputError(
            f"{source}: the calibration's principal point ({camera.cx:.1f}, {camera.cy:.1f}) lies "
            f"{share:.0%} of the image off the centre of the {w}x{h} frames, and at no integer "
            "factor of their size near it: give the calibration of these frames"
        )
    return CalibrationFit(
        camera,
        f"{source}: the calibration puts the principal point ({camera.cx:.1f}, {camera.cy:.1f}) "
        f"{share:.0%} of the image off the centre of the {w}x{h} frames; kept as given, "
        "doubtful (a cropped image, or a calibration for other frames)",
    )
