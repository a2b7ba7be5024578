"""A calibration checked against the frames it is given for: one stated for another image size
is rescaled aloud (Hamlyn's rectified01, whose release states 320x240 for its 640x480 frames),
one that fits no size is refused in one line, one that fits is left as it is."""

from __future__ import annotations

from pathlib import Path

import pytest

from endopipe.cli import main
from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.calibration_check import fit_to_frames

#: The release's rectified calibration of rectified01, as it states it (for 320x240).
RELEASE_320 = "383.1901395 0 155.9659519195557\n0 383.1901395 124.3335933685303\n0 0 1\n"


def test_a_calibration_for_half_the_size_is_rescaled_aloud():
    as_read = Camera(width=640, height=480, fx=383.19, fy=383.19, cx=155.97, cy=124.33)
    fit = fit_to_frames(as_read, "hamlyn input")
    k = fit.camera
    # the 640-px camera: each pixel twice, centres kept (u640 = 2 u320 + 0.5)
    assert (k.fx, k.cx, k.cy) == pytest.approx((766.38, 312.44, 249.16))
    assert "320x240" in fit.said and "rescaled" in fit.said


def test_a_calibration_for_twice_the_size_is_rescaled_too():
    stated = Camera(width=320, height=240, fx=766.38, fy=766.38, cx=312.44, cy=249.16)
    k = fit_to_frames(stated, "x").camera
    assert (k.fx, k.cx, k.cy) == pytest.approx((383.19, 155.97, 124.33))


def test_a_central_calibration_is_left_as_it_is():
    k = Camera(width=640, height=480, fx=500, fy=500, cx=330.0, cy=230.0)
    fit = fit_to_frames(k, "x")
    assert fit.camera == k and fit.said is None


def test_a_principal_point_outside_the_frames_at_every_size_is_refused():
    k = Camera(width=640, height=480, fx=500, fy=500, cx=-40.0, cy=900.0)
    with pytest.raises(InputError, match="give the calibration of these frames"):
        fit_to_frames(k, "x")


def test_an_off_centre_point_no_size_explains_is_kept_and_called_doubtful():
    k = Camera(width=640, height=480, fx=500, fy=500, cx=440.0, cy=240.0)
    fit = fit_to_frames(k, "x")
    assert fit.camera == k and "doubtful" in fit.said


def hamlyn_with(root: Path, data: Path, intrinsics: str, frames: int = 3) -> Path:
    """The first frames of the shared real rectified01 (both eyes) beside a calibration."""
    seq = root / "rectified01"
    for sub in ("image01", "image02"):
        (seq / sub).mkdir(parents=True)
        for src in sorted((data / "hamlyn_rectified01" / "rectified01" / sub).iterdir())[:frames]:
            (seq / sub / src.name).symlink_to(src)
    (seq / "intrinsics.txt").write_text(intrinsics)
    src = data / "hamlyn_rectified01" / "rectified01" / "extrinsics.txt"
    (seq / "extrinsics.txt").write_text(src.read_text())
    return seq


def test_real_hamlyn_frames_with_the_release_calibration_as_stated(
    shared_data: Path, tmp_path: Path, capsys
):
    """The real 640x480 frames given the release's calibration for 320x240: one line says it
    was rescaled, and the case's camera is the one for 640x480 (the shared copy's own
    intrinsics.txt), so the stereo depth is metric, not twice off."""
    seq = hamlyn_with(tmp_path / "data", shared_data, RELEASE_320)
    work = tmp_path / "work"
    assert main(["run", str(seq), "--workdir", str(work), "--until", "ingest", "--quiet"]) == 0
    said = capsys.readouterr().err
    assert "it is one for 320x240 frames" in " ".join(said.split())
    (case,) = [p for p in work.iterdir() if (p / "01_ingest").is_dir()]
    k = IngestView(case / "01_ingest").intrinsics
    assert k is not None
    shared = (shared_data / "hamlyn_rectified01" / "rectified01" / "intrinsics.txt").read_text()
    fx, _, cx, _, fy, cy, *_ = (float(v) for v in shared.split())
    truth = Camera(width=640, height=480, fx=fx, fy=fy, cx=cx, cy=cy).scaled(k.width, k.height)
    assert (k.fx, k.cx, k.cy) == pytest.approx((truth.fx, truth.cx, truth.cy), abs=0.01)
    view = IngestView(case / "01_ingest")
    assert "320x240" in view.summary.calibration_check
    assert view.summary.warnings[0] == view.summary.calibration_check
